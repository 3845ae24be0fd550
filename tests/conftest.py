"""Shared fixtures: real tables in real shared memory, removed after each test; and two checks on every
test, autouse: it leaves no segment, semaphore or queue behind, and it starts processes only if it
is marked `multiprocess`.

Plain helpers (names, specs, fakes) are in tests/support.py; test files import those, never each other.
"""

from __future__ import annotations

import multiprocessing.process
import os
import sys
import tempfile
from pathlib import Path

import mujoco  # noqa: F401  (imported before any test: its first import probes the GL library in a child process)
import pytest
from hypothesis import settings

from pbo_runtime.config.model import VariableSpec
from pbo_runtime.table.table import StateTable, TableLayout
from tests.support import unique_name

# `pytest --hypothesis-profile=long`: the property tests that read the profile (tests/test_check_runs.py)
# draw this many examples instead of CI's few; PBO_LONG_EXAMPLES sets another count for a run by hand
settings.register_profile("long", max_examples=int(os.environ.get("PBO_LONG_EXAMPLES", "2000")), deadline=None)

# the suite's own result cache (pbo_runtime.objects.result_cache): nothing read from the user's, nothing left in it
_RESULT_CACHE = tempfile.TemporaryDirectory(prefix="pbo-test-cache-")
os.environ.setdefault("PBO_CACHE_DIR", _RESULT_CACHE.name)


@pytest.fixture
def make_table():
    """Create real tables; every one is closed and unlinked after the test."""
    made: list[StateTable] = []

    def make(var_specs: list[VariableSpec], n_tasks: int = 4) -> StateTable:
        table = StateTable.create(TableLayout.build(var_specs, n_tasks), unique_name())
        made.append(table)
        return table

    yield make
    for table in made:
        table.close()


@pytest.fixture(autouse=True)
def no_leftover_ipc():
    """Fail any test that leaves behind a segment, semaphore or queue named with this test process's pid.

    That is every name `unique_name` makes (`pbo.test.<pid>-...`) and every run this process starts or
    fakes (`pbo.<subsystem>.<pid>-...`); objects of other processes, other test runs on the machine
    included, do not count (queues only where /dev/mqueue is mounted). Autouse, and so set up before
    and torn down after every fixture a test asks for: whatever made the object has closed it by then.
    Leftovers are removed before the failure is reported, so one test's leak does not fail the next.
    """
    mine = f".{os.getpid()}-"

    def ours() -> set[Path]:
        found: set[Path] = set()
        for folder in (Path("/dev/shm"), Path("/dev/mqueue")):
            if folder.is_dir():
                found |= {folder / entry for entry in os.listdir(folder) if mine in entry}
        return found

    before = ours()
    yield
    left = ours() - before
    for path in left:
        path.unlink(missing_ok=True)
    assert not left, f"left behind: {sorted(map(str, left))}"


# --- processes a test starts ------------------------------------------------------------------------

_started: list[str] = []  # what the running test started, by the audit hook below


def _note_a_started_process(event: str, args: tuple) -> None:
    """Audit hook: note each child this process starts that is a Python process (pbo, an RTPU, a plant, a script).

    Every subprocess goes through the "subprocess.Popen" event and every fork through "os.fork";
    a tool a library runs now and then (a font cache, a linker lookup) is not a Python process and
    does not count.
    """
    if event == "subprocess.Popen":
        executable, command = args[0], args[1]
        program = executable or (command[0] if isinstance(command, (list, tuple)) and command else command)
        if program is not None and Path(os.fsdecode(program)).name.startswith("python"):
            _started.append(" ".join(map(os.fsdecode, command)) if isinstance(command, (list, tuple)) else os.fsdecode(command))
    elif event in ("os.fork", "os.forkpty"):
        _started.append(event)


sys.addaudithook(_note_a_started_process)  # an audit hook stays for the process's life: it only appends to a list


@pytest.fixture(autouse=True)
def only_marked_tests_start_processes(request, monkeypatch):
    """Fail a test that starts a process (subprocess, fork, multiprocessing) unless it is marked `multiprocess`.

    `pytest -m "not multiprocess"` is then the quick suite, with nothing left out of it that starts
    a process. multiprocessing's spawn and forkserver start children without an audit event, so
    Process.start is noted here too.
    """
    start = multiprocessing.process.BaseProcess.start

    def noted_start(process):
        _started.append(f"multiprocessing {process.name}")
        return start(process)

    monkeypatch.setattr(multiprocessing.process.BaseProcess, "start", noted_start)
    _started.clear()
    yield
    started = [what.split("\n")[0][:120] for what in _started]
    _started.clear()
    if started and request.node.get_closest_marker("multiprocess") is None:
        pytest.fail(f"this test starts processes but is not marked @pytest.mark.multiprocess: {'; '.join(started[:3])}",
                    pytrace=False)


# --- a small disk ------------------------------------------------------------------------------------


@pytest.fixture
def small_disk(tmp_path):
    """A 64 KiB tmpfs mounted in tmp_path/disk, unmounted after the test: a disk a test can fill.

    Root ignores file permissions, so a read-only directory proves nothing; a full file system
    refuses root too. Skipped where mounting is not allowed.
    """
    import subprocess

    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k,mode=0700", "tmpfs", str(disk)],
                             capture_output=True, text=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {mounted.stderr.strip()}")
    try:
        yield disk
    finally:
        subprocess.run(["umount", "-l", str(disk)], capture_output=True)



# --- a real browser for the HMI -----------------------------------------------------------------------


# What Chromium itself logs as an error that is the API's answer, not the page's failure: a refusal
# the page shows (404 no file, 409 ...), and the server gone at the test's end (a stream retries,
# a request in flight is refused).
BROWSER_NOTICES = ("Failed to load resource: the server responded with a status of", "WebSocket connection to ",
                   "Failed to load resource: net::ERR_CONNECTION_REFUSED")


@pytest.fixture(scope="session")
def browser():
    """Debian's Chromium, driven by Playwright (its own browser download is not used): headless, one per session.

    Where no Chromium can start, a browser test is skipped, except under CI=true, where it fails:
    CI installs Chromium (.ci/run), so a missing browser there is a broken setup, not a reason to pass.
    """
    from tests.support import chromium_executable, chromium_flags

    def unavailable(why: str):
        if os.environ.get("CI") == "true":
            pytest.fail(f"no browser for the HMI's tests under CI=true: {why}", pytrace=False)
        pytest.skip(f"no browser for the HMI's tests: {why}")

    try:
        from playwright.sync_api import Error as PlaywrightError
        from playwright.sync_api import sync_playwright
    except ImportError as exc:
        unavailable(f"playwright is not installed ({exc}); make .venv/.installed installs it")
    executable = chromium_executable()
    if executable is None:
        unavailable("no chromium on PATH (apt-get install chromium, or set PBO_CHROMIUM)")
    from playwright.sync_api import expect

    expect.set_options(timeout=60_000)  # a net for a page that never shows what is awaited, never a timing
    with sync_playwright() as playwright:
        try:
            launched = playwright.chromium.launch(executable_path=executable, headless=True, args=chromium_flags())
        except PlaywrightError as exc:
            unavailable(f"{executable} did not start: {str(exc).splitlines()[0]}")
        yield launched
        launched.close()


@pytest.fixture
def page(browser):
    """A fresh page 1280 px wide (the narrowest the HMI is laid out for); a script error on it fails the test."""
    context = browser.new_context(viewport={"width": 1280, "height": 900})
    opened = context.new_page()
    script_errors: list[str] = []
    opened.on("pageerror", lambda error: script_errors.append(str(error)))
    opened.on("console", lambda message: script_errors.append(message.text)
              if message.type == "error" and not message.text.startswith(BROWSER_NOTICES) else None)
    opened.on("response", lambda response: script_errors.append(f"{response.status} {response.url}")
              if "/static/" in response.url and response.status >= 400 else None)
    yield opened
    context.close()
    assert not script_errors, f"the page's scripts failed: {script_errors}"
