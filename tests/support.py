"""Plain helpers the test files share: names, specs, fakes, and checks on what a run left behind.

Fixtures live in conftest.py (pytest hands them to a test by its argument names); everything a
test file imports from elsewhere in tests/ comes from here, never from another test file.
"""

from __future__ import annotations

import contextlib
import functools
import itertools
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
import tracemalloc
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import posix_ipc
import pytest

from bench import _inject
from bench._inject import stop_process, stop_while_holding_the_lock  # noqa: F401 (the tests' way to cause them)
from pbo_runtime import OutVar, PortBasedObject, Status
from pbo_runtime.clock.clocks import ManualClock
from pbo_runtime.config.model import PortBinding, TaskSpec, VariableSpec
from pbo_runtime.ipc.shm import children_of
from pbo_runtime.ipc.shm import pid_state as process_state  # (for the tests)
from pbo_runtime.task.lifecycle import Task

REPO = Path(__file__).resolve().parent.parent
DEMO = REPO / "configs" / "pid_joint.yaml"
PBO = [sys.executable, "-m", "pbo_runtime.cli"]  # the `pbo` command, run by the interpreter running the tests


# --- names and specs -------------------------------------------------------------------------


def unique_name(part: str = "table") -> str:
    """A run-style object name no other test or run uses; `no_leftover_ipc` watches names with this pid."""
    return f"/pbo.test.{os.getpid()}-{uuid.uuid4().hex[:6]}.{part}"


def variables(*specs: tuple[str, str, tuple[int, ...]]) -> list[VariableSpec]:
    return [VariableSpec(name, i, dtype, shape) for i, (name, dtype, shape) in enumerate(specs)]


def task_spec(module: type[PortBasedObject], name: str = "t", index: int = 0, ports: dict[str, str] | None = None,
              dims: dict[str, int] | None = None, params: dict | None = None, period: float = 0.001) -> TaskSpec:
    """A TaskSpec binding each declared port to its default variable (or `ports[name]`)."""
    ports = ports or {}
    bindings = tuple(
        PortBinding(p, ports.get(p.name, p.variable), p.resolved_shape(dims or {})) for p in module.ports()
    )
    return TaskSpec(name=name, module=module.__name__, rtpu="rtpu0", period=period, params=params or {},
                    bindings=bindings, index=index)


def make_task(table, module, name: str, ports: dict[str, tuple[str, tuple[int, ...]]], links: dict, relay=None,
              params: dict | None = None, index: int = 0, aperiodic: bool = False) -> Task:
    """A task of a link module (sender, server, receiver) on `table`, its ports bound to (variable, shape)."""
    bindings = tuple(PortBinding(p, ports[p.name][0], ports[p.name][1]) for p in module.ports())
    spec = TaskSpec(name=name, module=module.__name__, rtpu="rtpu0", period=0.01, params=params or {"link": "goal"},
                    bindings=bindings, index=index, aperiodic=aperiodic, min_interarrival=0.01 if aperiodic else None)
    return Task(spec, module, table, links=links, relay=relay)


# --- fakes for an executive on a manual clock ----------------------------------------------------

RUNS: list[tuple[str, float]] = []  # (task, release time) of every Ticker cycle; cleared by the tests that read it


class Ticker(PortBasedObject):
    """Fake module: records (task, release time) on every cycle; may take simulated time."""

    out = OutVar("out")
    cost = 0.0
    clock: ManualClock | None = None

    def cycle(self) -> Status:
        RUNS.append((self.task_name, self.time))
        if self.cost and self.clock is not None:
            self.clock.advance(self.cost)
        return Status.CONTINUE


class Quiet(PortBasedObject):
    """Fake module: a cycle that allocates nothing (Ticker records every cycle in a list)."""

    out = OutVar("out")

    def cycle(self) -> Status:
        return Status.CONTINUE


class FakeSignals:
    """Fake signal queue: scripted (time, message) pairs; waiting moves the manual clock."""

    def __init__(self, clock: ManualClock, script: list[tuple[float, list]]) -> None:
        self.clock = clock
        self.script = sorted(script, key=lambda item: item[0])

    def receive(self, timeout):
        deadline = self.clock.now() + (timeout or 0.0)
        if self.script and self.script[0][0] <= deadline:
            at, message = self.script.pop(0)
            self.clock.time = max(self.clock.time, at)
            return message
        self.clock.time = max(self.clock.time, deadline)
        return None


def run_until(executive, clock: ManualClock, end: float) -> None:
    """Step the executive (rtpu._executive.Executive) through every release and signal due at or before `end`."""
    while executive.running:
        next_release = min((s.release for s in executive.on), default=float("inf"))
        script = executive.signals.script
        next_signal = script[0][0] if script else float("inf")
        if min(next_release, next_signal) > end:
            return
        executive.run_once()


class IdleSignals:
    """Fake signal queue for executives stepped together (`step_executives`): signals are handed
    to `Executive.handle` directly; waiting moves the shared manual clock."""

    def __init__(self, clock: ManualClock) -> None:
        self.clock = clock

    def receive(self, timeout):
        self.clock.time = max(self.clock.time, self.clock.time + (timeout or 0.0))
        return None


def next_event(executive) -> float:
    """When the executive next has something to do: a release, or a plan's activation."""
    from pbo_runtime.table.table import Header

    times = [s.release for s in executive.on]
    if executive.header[Header.PLAN_SEQUENCE] != executive.plans.seen:
        times.append(executive.header[Header.PLAN_TIME_NS] / 1e9)
    return min(times, default=float("inf"))


def step_executives(executives: dict, clock: ManualClock, end: float) -> None:
    """Discrete-event loop over executives sharing one table and one manual clock: run the one
    whose next event is earliest, until `end`. Leaving one out of `executives` is an RTPU that
    stopped (SIGSTOP): its tasks release nothing, its outputs age."""
    while True:
        _name, executive = min(executives.items(), key=lambda item: next_event(item[1]))
        due = next_event(executive)
        if due > end:
            clock.time = max(clock.time, end)
            return
        clock.time = max(clock.time, due)
        executive.run_once()


# --- allocations on a per-cycle path -------------------------------------------------------------


def allocation_peak(call, times: int = 1000) -> int:
    """Bytes `times` calls of `call` have alive at once at most, beyond what the loop itself needs.

    A per-cycle path that allocated even one small array per call would show it (the array object
    and its data), however briefly it lived; what a path without arrays shows is Python's own
    boxing of the integers a seqlock read or a handshake returns.
    """
    def loop(body):
        for _ in range(times):
            body()

    def nothing():
        pass

    loop(call)  # first calls fill caches
    tracemalloc.start()
    try:
        measured = []
        for _ in range(3):  # tracemalloc sees every thread: the least of three leaves out another thread's
            peaks = []      # allocation that fell in one of them; the path's own shows in each
            for body in (nothing, call):
                tracemalloc.reset_peak()
                start, _ = tracemalloc.get_traced_memory()
                loop(body)
                _, peak = tracemalloc.get_traced_memory()
                peaks.append(peak - start)
            measured.append(peaks[1] - peaks[0])
    finally:
        tracemalloc.stop()
    return min(measured)


def one_array() -> int:
    """The allocation peak of making one 6-element array per call: what a per-cycle path must stay under."""
    return allocation_peak(lambda: np.empty(6))


# --- waiting for what another end does -------------------------------------------------------------


def until(condition, what: str, safety_net: float = 30.0) -> None:
    """Poll `condition` until it holds; fail after `safety_net` seconds, which only turns a hang into a
    failure (no test asserts on time)."""
    give_up = time.monotonic() + safety_net
    while not condition():
        if time.monotonic() > give_up:
            pytest.fail(f"gave up waiting: {what}")
        time.sleep(0.001)


# --- items of a link that show a torn copy -------------------------------------------------------


def checksum(counter: int) -> int:
    return (counter * 0x9E37_79B9_7F4A_7C15) % (1 << 64)


def fill(item: np.ndarray, counter: int) -> None:
    """Write item `counter` of a (counter, values, checksum) payload: every field derives from the counter."""
    item["counter"] = counter
    item["values"] = counter
    item["checksum"] = checksum(counter)


def assert_complete(item: np.ndarray, counter: int) -> None:
    """The item is exactly the one the sender wrote with this counter: every field agrees."""
    assert int(item["counter"]) == counter
    values = item["values"]
    assert values.min() == values.max() == counter, f"torn item: values {values.min()}..{values.max()}, counter {counter}"
    assert int(item["checksum"]) == checksum(counter)


# --- runs in real processes ----------------------------------------------------------------------


def subsystem_copy(directory: Path, subsystem: str, exclusive: bool = True) -> Path:
    """configs/pid_joint.yaml as subsystem `subsystem` on one RTPU, in `directory`, its arm exclusive or not.

    Runs of one subsystem with an exclusive device refuse each other, and other test runs on the
    machine use the shipped names: a test that starts runs gives them a name of its own. One RTPU
    keeps a run's share of the per-user queue memory (`ulimit -q`) small when several run at once.
    """
    text = DEMO.read_text()
    for old, new in (("\nsubsystem: puma", f"\nsubsystem: {subsystem}"), ("rtpus: [rtpu0, rtpu1]", "rtpus: [rtpu0]"),
                     ("rtpu: rtpu1", "rtpu: rtpu0"), ("exclusive: true", f"exclusive: {str(exclusive).lower()}")):
        assert old in text, old
        text = text.replace(old, new)
    path = directory / f"{subsystem}.yaml"
    path.write_text(text)
    return path


def ipc_names(fragment: str) -> list[str]:
    """The names in /dev/shm, and in /dev/mqueue where it is mounted (not on every machine), that hold `fragment`."""
    folders = ["/dev/shm", *(["/dev/mqueue"] if os.path.ismount("/dev/mqueue") else [])]
    return [name for folder in folders for name in os.listdir(folder) if fragment in name]


def run_objects(table: str) -> list[tuple[str, str]]:
    """(kind, POSIX name) of every object of the run whose table is `table`, read while the run lives: its
    table's manifest (which names the queues, not listed where /dev/mqueue is not mounted) and /dev/shm."""
    from pbo_runtime.ipc.shm import list_objects
    from pbo_runtime.supervisor.cleanup import read_run_manifest

    run_id = table.split(".")[2]
    entries, _pids = read_run_manifest(table)
    return sorted({*entries, *((o.kind, o.name) for o in list_objects() if o.run_id == run_id)})


def objects_left(objects: list[tuple[str, str]]) -> list[str]:
    """The names among `objects` (`run_objects`) that still exist, each opened by name, and whatever
    else of their run /dev/shm holds."""
    opener = {"shm": posix_ipc.SharedMemory, "sem": posix_ipc.Semaphore, "mq": posix_ipc.MessageQueue}
    left = []
    for kind, name in objects:
        try:
            made = opener[kind](name)
        except posix_ipc.ExistentialError:
            continue
        made.close_fd() if kind == "shm" else made.close()
        left.append(name)
    runs = {name.split(".")[2] for _kind, name in objects}
    listed = {"/" + (n[4:] if n.startswith("sem.") else n) for run in runs for n in ipc_names(run)}
    return sorted({*left, *listed})


def process_gone(pid: int) -> bool:
    """Whether process `pid` has ended (a zombie has)."""
    return process_state(pid) in ("", "Z", "X")


def assert_nothing_left(report: dict) -> None:
    """Every object the run made is gone: opened by name, since /dev/mqueue may not be mounted."""
    assert report["objects"], "the report lists the run's objects"
    opener = {"shm": posix_ipc.SharedMemory, "sem": posix_ipc.Semaphore, "mq": posix_ipc.MessageQueue}
    for entry in report["objects"]:
        kind, name = entry.split(" ", 1)
        with pytest.raises(posix_ipc.ExistentialError):
            opener[kind](name)
    leftovers = [n for n in os.listdir("/dev/shm") if report["run_id"] in n]
    assert leftovers == []


def demo_copy(folder: Path, subsystem: str, *, source: Path = DEMO, **tasks: dict) -> Path:
    """The demo's YAML (or `source`, another of configs/) under another subsystem name (runs side by
    side never share one), with `tasks` entries updated key by key (a task the file lacks is added to
    its first configuration), written to `folder`."""
    import yaml

    config = yaml.safe_load(source.read_text())
    config["subsystem"] = subsystem
    for name, update in tasks.items():
        if name not in config["tasks"]:
            next(iter(config["configurations"].values())).append(name)
        config["tasks"].setdefault(name, {}).update(update)
    path = folder / f"{subsystem}.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path



_DDS_DOMAINS = itertools.count()


def ros2_peer(*arguments: object) -> subprocess.Popen:
    """`python -m tests.ros2_peer ARGUMENTS`: a ROS 2 node's side of the DDS wire, in a process of its own."""
    return subprocess.Popen([sys.executable, "-m", "tests.ros2_peer", *map(str, arguments)], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def ros2_peer_said(process: subprocess.Popen, safety_net: float = 120.0) -> dict:
    """The JSON line a ros2_peer printed last, once it ended well."""
    out, err = run_output(process, timeout=safety_net)
    assert process.returncode == 0, err
    return json.loads(out.strip().splitlines()[-1])


def own_dds_domain() -> int:
    """A DDS domain id (1-232) of the calling test's own, from this process's pid and a count: tests
    of the ROS 2 bridge running side by side never see each other's topics."""
    return 1 + (os.getpid() * 7 + next(_DDS_DOMAINS)) % 232


def dead_pid() -> int:
    """The pid of a process that has ended (a run id with it names a dead run)."""
    child = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    return int(child.stdout)


def application_copy(folder: Path, prefix: str, links: str | None = None) -> Path:
    """configs/leader_follower.yaml with its subsystem files, written to `folder`, the application named
    `prefix` and each subsystem `prefix`_<its name> (runs side by side never share one); `links`, if
    given, replaces the file's links section (the lines below `links:`)."""
    configs = REPO / "configs"
    for part in ("leader", "follower"):
        text = (configs / f"{part}.yaml").read_text()
        (folder / f"{part}.yaml").write_text(text.replace(f"\nsubsystem: {part}\n", f"\nsubsystem: {prefix}_{part}\n"))
    text = (configs / "leader_follower.yaml").read_text()
    text = text.replace("application: leader_follower", f"application: {prefix}")
    text = text.replace("subsystem: operator", f"subsystem: {prefix}_operator")
    if links is not None:
        text = text[:text.index("links:\n")] + "links:\n" + links + text[text.index("run:\n"):]
    path = folder / "app.yaml"
    path.write_text(text)
    return path


def config_copy(config: Path, folder: Path, subsystem: str, replace: tuple[tuple[str, str], ...] = ()) -> Path:
    """A shipped configs/ file under another subsystem name (runs side by side never share one),
    comments kept, each (old, new) of `replace` applied once it is found, written to `folder`."""
    text = config.read_text()
    text, count = re.subn(r"(?m)^subsystem: \S+$", f"subsystem: {subsystem}", text)
    assert count == 1, f"{config} names its subsystem once"
    for old, new in replace:
        assert old in text, old
        text = text.replace(old, new)
    path = folder / f"{subsystem}.yaml"
    path.write_text(text)
    return path

# Faults a real-clock run reports when the machine is slow or busy: a critical task held while its
# writer ran late, or while the plant was starved, or the arm's drive watchdog holding it while the
# robot interface was starved. A smoke test does not judge the machine's timing
# (bench/faults.py measures it); the fault tests (tests/test_faults.py) cause them on purpose.
TIMING_FAULTS = ("critical task '", "the plant did not run for ", "the arm's drive watchdog held the arm")


def assert_ended_well(returncode: int, report: dict, said: str = "") -> None:
    """A real-clock run ended as asked: exit 0, or exit 2 for timing faults only (nothing else failed)."""
    if returncode == 2 and not report["failure"] and report["faults"]:
        assert all(fault.startswith(TIMING_FAULTS) for fault in report["faults"]), report["faults"]
        return
    assert returncode == 0, said or report


# --- faults in a real run: stopped processes, a held table lock ----------------------------------


SAYING_SAFETY_NET = 180.0  # seconds a run may take to say what a test waits for: a net for a hang, not a timing


def read_until(run: subprocess.Popen, *texts: str, safety_net: float = SAYING_SAFETY_NET) -> str:
    """What `run` printed up to the line by which it has said every one of `texts` (all of it if it ended first).

    A run that has said neither all of them nor its last line after `safety_net` seconds is
    stopped (Ctrl-C, then SIGKILL) and the test fails with what it said: a missing line never
    hangs the suite."""
    assert run.stdout is not None
    said: list[str] = []
    waiting = set(texts)

    def read() -> None:
        for line in run.stdout:
            said.append(line)
            waiting.difference_update([text for text in waiting if text in line])
            if not waiting:
                return

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(safety_net)
    if reader.is_alive():
        run.send_signal(signal.SIGINT)
        try:
            run.wait(timeout=60)
        except subprocess.TimeoutExpired:
            run.kill()
            run.wait()
        reader.join()
        pytest.fail(f"the run did not say {sorted(waiting)} within {safety_net:.0f} s; it said:\n{''.join(said)}")
    return "".join(said)


def start_run(file: Path, cwd: Path, *arguments: str, live: bool = False) -> subprocess.Popen:
    """`pbo run FILE --no-live ...` in `cwd` (without --no-live when `live`: live changes on), returned once
    its configuration is on (stdout read up to that line)."""
    run = subprocess.Popen([*PBO, "run", str(file), *([] if live else ["--no-live"]), *arguments], cwd=cwd,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if "is on" not in read_until(run, "is on"):
        run.wait(timeout=60)
        pytest.fail(f"the run did not start: {run.stderr.read() if run.stderr else ''}")
    return run


def run_processes(run: subprocess.Popen) -> dict[str, int]:
    """role ('plant', 'rtpu0', ...) -> pid of a live run's children."""
    roles = {}
    for pid, command in children_of(run.pid).items():
        words = command.split()
        if "--rtpu" in words:
            roles[words[words.index("--rtpu") + 1]] = pid
        elif "pbo_runtime.supervisor.plant_host" in command and "fork_server" not in command:  # (the kept server preloads it)
            roles["plant"] = pid
    return roles


def kill_and_await_restart(run: subprocess.Popen, rtpu: str = "rtpu0", pid: int | None = None) -> int:
    """SIGKILL a live run's RTPU (its `pid`, when looked up already), then read on until the run says
    it restarted it; the killed pid."""
    pid = pid or run_processes(run)[rtpu]
    os.kill(pid, signal.SIGKILL)
    said = read_until(run, "restarted:")
    assert f"RTPU '{rtpu}' (pid {pid}) died (killed by SIGKILL)" in said, said
    return pid


@contextlib.contextmanager
def killed_on_failure(run: subprocess.Popen) -> Iterator[None]:
    """A test that fails while its run goes on kills the run: nothing is left behind."""
    try:
        yield
    except BaseException:
        if run.poll() is None:
            run.kill()
            run.wait()
        raise


def run_output(run: subprocess.Popen, timeout: float = 120.0) -> tuple[str, str]:
    """(stdout, stderr) of a run once it ends; one still going after `timeout` (a net for a hang) is killed."""
    try:
        return run.communicate(timeout=timeout)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()


def table_of(run: subprocess.Popen, subsystem: str) -> str:
    """The POSIX name of the table of the run whose supervisor is `run`."""
    return _inject.table_of(subsystem, run.pid)


def assert_ended_cleanly(run: subprocess.Popen, subsystem: str, report_path: Path, status: int | None) -> tuple[str, str]:
    """The run ends (a generous safety net, no timing), with `status` (None: 0, or 2 for the faults
    of stopped processes only, see `assert_ended_well`), no traceback, and nothing left; (stdout, stderr)."""
    out, err = run_output(run)
    if status is None:
        assert_ended_well(run.returncode, json.loads(report_path.read_text()), err)
    else:
        assert run.returncode == status, f"exit {run.returncode}, expected {status}:\n{err}"
    assert "Traceback" not in err and "internal error" not in err, err
    assert "run summary" in out, "the summary is printed"
    assert children_of(run.pid) == {}
    report = json.loads(report_path.read_text())
    assert_nothing_left(report)
    assert [e for e in os.listdir("/dev/shm") if f"pbo.{subsystem}.{run.pid}-" in e] == []
    return out, err
def only_file(folder: Path, pattern: str) -> Path:
    """The one file under `folder` matching the glob `pattern` (a run's log in its dated directory)."""
    found = sorted(folder.glob(pattern))
    assert len(found) == 1, f"{pattern} under {folder}: {found}"
    return found[0]


def fill_disk(disk: Path, leave: int = 0) -> None:
    """Fill the file system of `disk` until at most `leave` bytes are free."""
    free = os.statvfs(disk)
    room = free.f_bavail * free.f_frsize - leave
    if room > 0:
        (disk / "filler").write_bytes(b"\0" * room)


# Plant options for tests that step an in-process arm by hand, with no controller writing
# commands: its drive watchdog (which holds the arm once commands stop) is off.
NO_WATCHDOG = {"command_timeout": 0}


def live_demo_copy(folder: Path, subsystem: str) -> Path:
    """configs/pid_joint.yaml, comments kept, as subsystem `subsystem`, for live changes: without its
    logger (a live test spawns one: a module runs once a configuration), with a job and an application."""
    text = DEMO.read_text()
    logger = ("  logger: {module: data_logger, rtpu: rtpu0, period: 10 ms,\n"
              "           params: {variables: [q_m, q_r, tau_u], path: pid_joint.mcap}}\n")
    for old, new in (("\nsubsystem: puma\n", f"\nsubsystem: {subsystem}\n"), (logger, ""),
                     ("  joint_pid: [robot, traj, pid, logger]\n",
                      "  joint_pid: [robot, traj, pid]  # the PID loop\n"
                      "\njobs:\n  hold: {configuration: joint_pid, object: none, timeout: 100 ms}\n"
                      "\napplications:\n  settle: [hold]\n")):
        assert old in text, old
        text = text.replace(old, new)
    path = folder / f"{subsystem}.yaml"
    path.write_text(text)
    return path


# --- the browser HMI ------------------------------------------------------------------------------


CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")


def chromium_executable() -> str | None:
    """The Chromium the HMI's tests drive: $PBO_CHROMIUM, or Debian's on PATH."""
    import shutil

    if os.environ.get("PBO_CHROMIUM"):
        return os.environ["PBO_CHROMIUM"]
    return next((found for name in CHROMIUM_NAMES if (found := shutil.which(name))), None)


def chromium_flags() -> list[str]:
    """Chromium with nothing of its own on the network (this machine's network is closed: its background
    connections would be refused, many at a time), and without its sandbox when run as root."""
    flags = ["--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
             "--disable-component-update", "--disable-sync", "--disable-default-apps"]
    return flags + (["--no-sandbox"] if os.geteuid() == 0 else [])


def screenshot(page, name: str) -> None:
    """With PBO_SCREENSHOTS naming a folder (`make screenshots`: docs/), the whole page saved there as `name`."""
    folder = os.environ.get("PBO_SCREENSHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(folder) / name), full_page=True)


def open_user_level(page, url: str) -> None:
    """The HMI at `url` on its User tab, once the job dictionary shows."""
    from playwright.sync_api import expect

    page.goto(url)
    page.get_by_role("tab", name="User: applications from jobs").click()
    expect(page.locator("#pane-user")).to_be_visible()
    expect(page.locator(".dictionary [data-icon=reach]")).to_be_visible()


def icon(page, name: str):
    """The dictionary's icon `name` on the User tab."""
    return page.locator(f".dictionary [data-icon={name}]")


def row(page):
    """The application workspace's row."""
    return page.get_by_role("list", name="application workspace")


def message(page):
    """The line under the workspace's row."""
    return page.locator("[data-test=workspace-message]")


def check_clean(file: Path) -> str:
    """`pbo check FILE`'s output, once it says the file has no error."""
    checked = subprocess.run([*PBO, "check", str(file)], capture_output=True, text=True, timeout=60)
    assert checked.returncode == 0 and "error[" not in checked.stdout + checked.stderr, checked.stdout + checked.stderr
    return checked.stdout


def start_hmi(*arguments: str, cwd: Path | None = None) -> tuple[subprocess.Popen, str]:
    """`pbo hmi ARGUMENTS --port 0` and the URL it printed (with its token); the caller stops it (`stop_hmi`)."""
    hmi = subprocess.Popen([*PBO, "hmi", *arguments, "--port", "0"], cwd=cwd, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    said = read_until(hmi, "http://127.0.0.1:")
    urls = [word for word in said.split() if word.startswith("http://127.0.0.1:")]
    if not urls:
        said_on_stderr = stop_hmi(hmi)  # (it reads stderr to its end: nothing is left to read after it)
        pytest.fail(f"pbo hmi printed no URL (exit {hmi.returncode}): {said}{said_on_stderr}")
    return hmi, urls[0]


def stop_hmi(hmi: subprocess.Popen) -> str:
    """Ctrl-C to `pbo hmi`, as an operator stops it; what it wrote on stderr."""
    if hmi.poll() is None:
        hmi.send_signal(signal.SIGINT)
    try:
        return hmi.communicate(timeout=30)[1]
    except subprocess.TimeoutExpired:
        hmi.kill()
        return hmi.communicate()[1]


# --- the job canvas (engineer level) ---------------------------------------------------------------

# TR Figure 8 as the canvas sends it: tasks with their values as YAML text
FIGURE_8_CANVAS = [
    {"name": "robot", "module": "robot_torque", "fields": {"rtpu": "rtpu1", "period": "1 ms", "resources": "[arm]"}},
    {"name": "traj", "module": "joint_trajectory", "fields": {"rtpu": "rtpu0", "period": "2 ms"}},
    {"name": "pid", "module": "pid_joint", "fields": {"rtpu": "rtpu0", "period": "1 ms"}, "params": {"kp": "400"}},
    {"name": "logger", "module": "data_logger", "fields": {"rtpu": "rtpu0", "period": "10 ms"},
     "params": {"variables": "[q_m, q_r, tau_u]"}},
]


def canvas_base_file(folder: Path, name: str = "empty") -> Path:
    """configs/pid_joint.yaml's header (rtpus, plant, devices, dims, variables) with no task: an empty canvas's file."""
    header = DEMO.read_text().split("\ntasks:", 1)[0].replace("\nsubsystem: puma\n", f"\nsubsystem: {name}\n")
    path = folder / f"{name}.yaml"
    path.write_text(header + "\n# the canvas's jobs go here\ntasks: {}\n\nconfigurations: {}\n")
    return path


# --- the application workspace (user level) -------------------------------------------------------


# `pbo run` arguments for a run a page watches job by job: the simulated clock, no faster than real
# time, so a job of N simulated seconds is the current one for N wall seconds at least on any machine
WATCHED_SIM = ("--clock", "sim", "--pace", "1", "--duration", "0")


def user_level_copy(folder: Path, subsystem: str, reach_seconds: float = 6.0, hold_seconds: float = 600.0) -> Path:
    """configs/pid_joint.yaml, comments kept, as subsystem `subsystem`, for the HMI's user level: without
    its logger, with a joint_position object type, two named objects, a job that requires an object
    (`reach`: its trajectory reads q_d) and an action (`hold`), each running for its seconds (simulated
    on `--clock sim`; with WATCHED_SIM as many wall seconds at least, long enough for a page to see it
    as the current job), `hold` by default until the test stops the run."""
    text = DEMO.read_text()
    logger = ("  logger: {module: data_logger, rtpu: rtpu0, period: 10 ms,\n"
              "           params: {variables: [q_m, q_r, tau_u], path: pid_joint.mcap}}\n")
    objects = ("\nobject_types:                    # what a job's object may be\n"
               "  joint_position: {type: float64, shape: [NDOF], unit: rad, doc: \"a position of the six joints\"}\n"
               "objects:                         # named objects: a step gives one to a job by name\n"
               "  home:  {type: joint_position, value: 0}\n"
               "  ready: {type: joint_position, value: [0.3, -0.5, 0.5, 0.2, 0.4, 0.2], doc: \"upper arm raised\"}\n"
               "\ntasks:\n")
    jobs = (f"  joint_pid: [robot, traj, pid]  # the PID loop\n\njobs:\n"
            f"  reach: {{configuration: joint_pid, timeout: {reach_seconds:g} s}}   # requires a joint_position: traj reads q_d\n"
            f"  hold:  {{configuration: joint_pid, object: none, timeout: {hold_seconds:g} s}}\n")
    for old, new in (("\nsubsystem: puma\n", f"\nsubsystem: {subsystem}\n"), (logger, ""), ("\ntasks:\n", objects),
                     ("  joint_pid: [robot, traj, pid, logger]\n", jobs)):
        assert old in text, old
        text = text.replace(old, new, 1)
    path = folder / f"{subsystem}.yaml"
    path.write_text(text)
    return path


# --- DH oracles: an independent reading of a DH robot, to hold the plant's ARM table to -----------


def dh_pinocchio_model(dh: np.ndarray, dyn: np.ndarray):  # type: ignore[no-untyped-def]
    """A DH robot's Pinocchio model built straight from its DH and DYN rows (standard DH,
    T_i = Rz(q_i + theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i); COM and inertia in DH frame i), frames
    `joint<i>`, `link<i>` and `ee` (DH frame n). The runtime never builds it this way: it is the
    tests' second opinion on the model `pbo_runtime.arm_model` makes from the plant's ARM table."""
    import pinocchio

    from drivers.robots.description import dh_link_transform, inertia_matrix, rot_z

    def se3(transform: np.ndarray):  # type: ignore[no-untyped-def]
        return pinocchio.SE3(transform[:3, :3].copy(), transform[:3, 3].copy())

    model = pinocchio.Model()
    parent, parent_link = 0, np.eye(4)
    for i, (dh_row, dyn_row) in enumerate(zip(np.asarray(dh, float), np.asarray(dyn, float), strict=True), start=1):
        joint = model.addJoint(parent, pinocchio.JointModelRZ(), se3(parent_link @ rot_z(dh_row[0])), f"joint{i}")
        link = dh_link_transform(dh_row)
        rotation, offset = link[:3, :3], link[:3, 3]
        model.appendBodyToJoint(joint, pinocchio.Inertia(dyn_row[0], rotation @ dyn_row[1:4] + offset,
                                                         rotation @ inertia_matrix(dyn_row) @ rotation.T),
                                pinocchio.SE3.Identity())
        model.addBodyFrame(f"link{i}", joint, pinocchio.SE3.Identity(), int(model.nframes - 1))
        parent, parent_link = joint, link
    model.addFrame(pinocchio.Frame("ee", parent, se3(parent_link), pinocchio.FrameType.OP_FRAME))
    model.armature[:] = np.asarray(dyn, float)[:, 10]
    model.gravity = pinocchio.Motion(np.array([0.0, 0.0, -9.81]), np.zeros(3))
    return model


def dh_forward_kinematics(dh: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The 4x4 pose of DH frame n in the base frame: the plain product of the DH transforms."""
    from drivers.robots.description import dh_link_transform, rot_z

    pose = np.eye(4)
    for dh_row, qi in zip(np.asarray(dh, float), np.asarray(q, float), strict=True):
        pose = pose @ rot_z(qi + dh_row[0]) @ dh_link_transform(dh_row)
    return pose


#: Arms of the example-robot-data package (a test dependency: robot files no one here wrote),
#: by name: their URDF inside the package, for `package://example-robot-data/...`.
EXAMPLE_ROBOTS = {
    "ur5": "robots/ur_description/urdf/ur5_robot.urdf",
    "panda": "robots/panda_description/urdf/panda.urdf",
    "z1": "robots/z1_description/urdf/z1.urdf",
    "xarm7": "robots/xarm_description/urdf/xarm7.urdf",
    "so100": "robots/so_arm_description/urdf/so100.urdf",
}


def example_robot(name: str) -> str:
    """The `package://` URI of an example-robot-data arm."""
    return f"package://example-robot-data/{EXAMPLE_ROBOTS[name]}"


@functools.cache
def arm_tables(model: str) -> tuple[np.ndarray, np.ndarray]:
    """The ARM and EE constants the plant publishes for a registered robot (as its robot interface
    writes them to the table), read-only: for tests that write the robot's constants themselves."""
    from drivers.robots.plant_model import load_robot

    loaded = load_robot(model, REPO, 0.001, {})
    arm, ee = loaded.arm.copy(), loaded.ee.copy()
    arm.setflags(write=False)
    ee.setflags(write=False)
    return arm, ee


def arm_constants(n: int) -> list[tuple[str, str, tuple[int, ...]]]:
    """The robot interface's out-consts NDOF, ARM and EE as `variables()` specs, for `n` joints."""
    from pbo_runtime import Arm

    return [("NDOF", "int32", ()), ("ARM", "float64", (n, Arm.WIDTH)), ("EE", "float64", (Arm.EE_WIDTH,))]


def robot_state_table(make_table, model: str, *specs: tuple[str, str, tuple[int, ...]]):  # type: ignore[no-untyped-def]
    """A table with the robot interface's out-consts of `model` written (NDOF, ARM, EE), and `specs`:
    what the model-based modules read at spawn, without a plant."""
    arm, ee = arm_tables(model)
    table = make_table(variables(*arm_constants(len(arm)), *specs))
    table.write("NDOF", len(arm), when=0.0)
    table.write("ARM", arm, when=0.0)
    table.write("EE", ee, when=0.0)
    return table


def spawned_task(table, module: type[PortBasedObject], dims: dict[str, int], params: dict | None = None,
                 period: float = 0.001) -> Task:
    """A real Task of `module` on `table`, spawned (its init run); fails the test if spawn failed."""
    task = Task(task_spec(module, dims=dims, params=params, period=period), module, table, dims)
    assert task.spawn(0.0), task.last_error
    return task


def write_values(table, when: float = 0.0, **values) -> None:
    """Write each keyword's value to the variable of that name, stamped `when`."""
    for name, value in values.items():
        table.write(name, value, when=when)


def excursion_from_path(q: np.ndarray, start: np.ndarray, goal: np.ndarray) -> float:
    """How far the arm left its path: each joint travels from start to goal, so any motion back
    from the farthest it got, or past the goal, is an excursion (rad, the largest over joints)."""
    direction = np.sign(goal - start)
    progress = (q - start) * direction  # rad travelled towards the goal, per joint
    back = np.maximum.accumulate(progress, axis=0) - progress
    past = progress - np.abs(goal - start)
    return float(max(back.max(), past.max(), 0.0))


# --- the demo's arm in a live run ------------------------------------------------------------------

DEMO_GOAL = np.array([0.3, -0.5, 0.5, 0.2, 0.4, 0.2])  # q_d's initial value in configs/pid_joint.yaml
DEMO_START = np.zeros(6)  # the PUMA's home pose, where the demo's plant starts
# The demo's move mid-way: its longest joints (0.5 rad at 1 rad/s, 4 rad/s²) have gone 0.175 rad,
# 0.3 s into the move and cruising at full speed.
DEMO_MID_MOVE = 0.175


@contextlib.contextmanager
def measured_arm(config: Path, run: subprocess.Popen, subsystem: str) -> Iterator[Callable[[], np.ndarray]]:
    """A live run's q_m, read lock-free from its table each call."""
    from pbo_runtime.config.loader import load_subsystem
    from pbo_runtime.table.table import StateTable, TableLayout

    table = StateTable.attach(TableLayout.of(load_subsystem(config)), table_of(run, subsystem))
    try:
        yield lambda: table.read("q_m")[0]
    finally:
        table.close()


def travelled(q: np.ndarray) -> float:
    """How far the demo's arm has gone from its start, rad (the joint that went farthest)."""
    return float(np.abs(q - DEMO_START).max())


def settling(goal: np.ndarray, within: float, reads: int = 200) -> Callable[[np.ndarray], bool]:
    """A check of successive readings of q_m: True once `reads` in a row are all within `within`
    of `goal` (the arm stays there, not just passing through)."""
    in_a_row = [0]

    def settled(q: np.ndarray) -> bool:
        in_a_row[0] = in_a_row[0] + 1 if np.abs(q - goal).max() < within else 0
        return in_a_row[0] >= reads

    return settled


class EventsHeard:
    """An `EventLedger` with fake outlets, for the supervisor's event handling without a process: the
    lines it says, and what it handed on (`handed`: the outlets' calls, in order)."""

    def __init__(self, not_critical: tuple[str, ...] = (), running: bool = True) -> None:
        from pbo_runtime.supervisor.event_ledger import EventLedger, EventOutlets
        from pbo_runtime.supervisor.run_report import RunResult

        self.lines: list[str] = []
        self.handed: list[tuple] = []
        self.running = running
        outlets = EventOutlets(switches=self, staged=lambda *staged: self.handed.append(("staged", *staged)),
                               count_errors=lambda: self.handed.append(("count_errors",)),
                               child_exited=lambda: self.handed.append(("child_exited",)),
                               running=lambda: self.running)
        self.result = RunResult("test", "c")
        self.ledger = EventLedger(self.result, self.lines.append, outlets, lambda task: task not in not_critical)

    def hear(self, source: str, *events) -> None:
        for event in events:
            self.ledger.absorb(source, event)

    def switched(self, *report) -> None:
        self.handed.append(("switched", *report))

    def window(self, *counts) -> None:
        self.handed.append(("window", *counts))

    def first_cycle(self, *first) -> None:
        self.handed.append(("first_cycle", *first))
