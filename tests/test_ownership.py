"""Whose objects a run trusts (issue 18): only the caller's, mode 0600; cleanup never touches a live run.

/dev/shm is writable by every user. Here other users' objects are planted two ways: by chown as
root (the unit tests), and by a child that really runs as another uid (`nobody`, 65534) next to
a live run (the end-to-end test). Runs of one subsystem name: `pbo runs`, `--run ID`, and the
refusal of a second run of a subsystem whose exclusive devices are in use.
"""

from __future__ import annotations

import json
import os
import subprocess
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import posix_ipc
import pytest

from pbo_runtime.cli.main import main
from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.ipc import messages, shm
from pbo_runtime.ipc import runs as run_finding
from pbo_runtime.ipc.runs import live_runs
from pbo_runtime.supervisor.cleanup import read_run_manifest, remove_dead_runs
from pbo_runtime.supervisor.run_options import RunOptions
from pbo_runtime.supervisor.supervisor import RunRefused, Supervisor
from pbo_runtime.table.table import HEADER_WORDS, MAGIC, MANIFEST_BYTES, VERSION, Header, StateTable, TableLayout
from tests.support import PBO, read_until, subsystem_copy, variables

NOBODY = 65534
VARS = variables(("q_m", "float64", (3,)))
NO_SUCH_PID = int(Path("/proc/sys/kernel/pid_max").read_text()) + 1  # no process can have it: a dead run's pid

as_root = pytest.mark.skipif(os.geteuid() != 0, reason="planting another user's objects takes root (CI runs as root)")


def new_subsystem(prefix: str = "own") -> str:
    return f"{prefix}{uuid.uuid4().hex[:6]}"


def run_id(pid: int) -> str:
    return f"{pid}-{uuid.uuid4().hex[:6]}"


def exists(kind: str, name: str) -> bool:
    return shm.look_at(kind, name)[0]


def fake_table_bytes(manifest: list[str]) -> bytes:
    """A table segment's bytes as far as cleanup reads them: a header and a manifest."""
    header = np.zeros(HEADER_WORDS, dtype=np.int64)
    header[Header.MAGIC], header[Header.VERSION] = MAGIC, VERSION
    header[Header.MANIFEST_OFFSET] = HEADER_WORDS * 8
    header[Header.TOTAL_BYTES] = HEADER_WORDS * 8 + MANIFEST_BYTES
    text = "\n".join(manifest).encode()
    return header.tobytes() + text + bytes(MANIFEST_BYTES - len(text))


class Planted:
    """Files planted in /dev/shm by a test; each is removed (as root) after it."""

    def __init__(self) -> None:
        self.paths: list[Path] = []

    def name(self, subsystem: str, pid: int, part: str) -> str:
        name = shm.object_name(subsystem, run_id(pid), part)
        self.paths.append(shm.SHM_DIR / name.lstrip("/"))
        return name

    def as_root(self, name: str, data: bytes, mode: int, uid: int = 0) -> None:
        """Plant as this (root) process, then give it `mode` and owner `uid`."""
        path = shm.SHM_DIR / name.lstrip("/")
        descriptor = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY | os.O_NOFOLLOW, 0o600)
        try:
            os.write(descriptor, data)
            os.fchmod(descriptor, mode)
            os.fchown(descriptor, uid, uid)
        finally:
            os.close(descriptor)

    def remove(self) -> None:
        for path in self.paths:
            path.unlink(missing_ok=True)


@pytest.fixture
def planted() -> Iterator[Planted]:
    made = Planted()
    yield made
    made.remove()


@pytest.fixture
def tables() -> Iterator[Any]:
    """Real run tables (root's, 0600), named for a run of (subsystem, pid); closed and unlinked after the test."""
    made: list[StateTable] = []

    def make(subsystem: str, pid: int, manifest: list[str] | None = None) -> StateTable:
        name = messages.table_name(subsystem, run_id(pid))
        table = StateTable.create(TableLayout.build(VARS, 1), name, [f"shm {name}", f"sem {name}.lock", *(manifest or [])])
        made.append(table)
        return table

    yield make
    for table in made:
        table.close()


def dead(table: StateTable) -> None:
    """Leave the table's objects behind, as a run killed outright does."""
    table.owner = False
    table.close()


# --- cleanup -------------------------------------------------------------------------------------


def test_cleanup_follows_a_manifest_only_to_names_of_its_own_run(tables):
    sub = new_subsystem()
    live = tables(sub, os.getpid())
    queue_name = messages.event_queue_name(sub, live.name.split(".")[2])
    live_queue = messages.Queue(queue_name, create=True)
    try:
        dead_run = tables(sub, NO_SUCH_PID)
        own_queue = messages.event_queue_name(sub, dead_run.name.split(".")[2])
        left = messages.Queue(own_queue, create=True)
        left.owner = False  # left behind with the dead run
        left.close()
        dead_run.set_manifest([f"shm {dead_run.name}", f"sem {dead_run.name}.lock", f"mq {own_queue}",
                               f"shm {live.name}", f"sem {live.name}.lock", f"mq {queue_name}"])
        dead(dead_run)
        cleanup = remove_dead_runs(sub)
        assert cleanup.removed == sorted([dead_run.name, f"{dead_run.name}.lock", own_queue])
        assert exists("shm", live.name) and exists("sem", f"{live.name}.lock") and exists("mq", queue_name)
        assert cleanup.live == [live.name.split(".")[2]]
    finally:
        live_queue.close()


def test_cleanup_leaves_a_dead_supervisors_run_alone_while_a_process_its_manifest_records_lives(tables):
    sub = new_subsystem()
    table = tables(sub, NO_SUCH_PID, [f"pid {os.getpid()} rtpu0"])  # a stopped RTPU outlives its killed supervisor
    cleanup = remove_dead_runs(sub)
    assert cleanup.removed == [] and cleanup.live == [table.name.split(".")[2]]
    assert exists("shm", table.name)
    table.set_manifest([f"shm {table.name}", f"sem {table.name}.lock", f"pid {NO_SUCH_PID} rtpu0"])
    dead(table)
    assert remove_dead_runs(sub).removed == sorted([table.name, f"{table.name}.lock"])


@as_root
@pytest.mark.parametrize("mode, uid, why", [
    (0o600, NOBODY, f"owned by uid {NOBODY}"),
    (0o666, 0, "mode 0666, not 0600"),
    (0o644, 0, "mode 0644, not 0600"),
], ids=["another uid", "mode 0666", "mode 0644"])
def test_cleanup_ignores_and_counts_what_is_not_ours_with_mode_0600(planted, mode, uid, why):
    sub = new_subsystem()
    name = planted.name(sub, NO_SUCH_PID, "table")
    planted.as_root(name, fake_table_bytes([]), mode, uid)
    cleanup = remove_dead_runs(sub)
    assert cleanup.removed == [] and cleanup.ignored == {name: why}
    assert cleanup.ignored_summary() == f"1 {why}"
    assert exists("shm", name), "it was not touched"


@as_root
def test_pbo_clean_says_how_many_objects_it_ignored_and_why(planted, capsys):
    sub = new_subsystem()
    for mode, uid in ((0o600, NOBODY), (0o666, 0), (0o666, NOBODY)):
        planted.as_root(planted.name(sub, NO_SUCH_PID, "table"), b"", mode, uid)
    assert main(["clean", "--subsystem", sub]) == 0
    out = capsys.readouterr().out.replace("\n", "")
    assert "removed 0 object(s) left by dead runs" in out
    assert (f"ignored 3 object(s) named like a run's but not yours to trust (only uid 0's with mode 0600 are): "
            f"1 mode 0666, not 0600, 2 owned by uid {NOBODY}; not touched: ") in out
    assert all(path.exists() for path in planted.paths)


def test_a_queue_named_by_a_manifest_is_judged_through_its_descriptor_where_dev_mqueue_is_not_mounted(monkeypatch,
                                                                                                      tmp_path):
    monkeypatch.setattr(shm, "MQUEUE_DIR", tmp_path)  # not a mount: queues cannot be listed, only opened
    name = shm.object_name(new_subsystem(), run_id(os.getpid()), "events")
    queue = posix_ipc.MessageQueue(name, posix_ipc.O_CREX, mode=0o600, max_messages=1, max_message_size=64)
    try:
        assert shm.look_at("mq", name) == (True, None)
        os.fchmod(queue.mqd, 0o666)
        assert shm.look_at("mq", name) == (True, "mode 0666, not 0600")
    finally:
        queue.close()
        queue.unlink()
    assert shm.look_at("mq", name) == (False, None)


# --- finding runs --------------------------------------------------------------------------------


@as_root
def test_a_table_of_another_user_or_mode_is_no_run_even_named_after_a_live_pid(planted, tables):
    sub = new_subsystem()
    for mode, uid in ((0o600, NOBODY), (0o666, 0)):
        planted.as_root(planted.name(sub, 1, "table"), fake_table_bytes([]), mode, uid)
    assert live_runs(sub) == []
    mine = tables(sub, os.getpid())
    assert [run.table for run in live_runs(sub)] == [mine.name]


def test_a_table_whose_pid_now_names_a_process_started_after_it_is_a_dead_run(tables, monkeypatch):
    sub = new_subsystem()
    table = tables(sub, os.getpid())
    assert [run.table for run in live_runs(sub)] == [table.name]
    later = os.lstat(shm.SHM_DIR / table.name.lstrip("/")).st_ctime + 60
    monkeypatch.setattr(run_finding, "process_start_time", lambda pid: later)  # the pid was reused by a process started since
    assert live_runs(sub) == []
    dead(table)  # its supervisor "died": the table is a leftover, which cleanup removes though the pid lives
    assert remove_dead_runs(sub).removed == sorted([table.name, f"{table.name}.lock"])


def test_pbo_runs_lists_each_live_run_as_a_table_and_as_json(tables, capsys):
    sub = new_subsystem()
    first, second = tables(sub, os.getpid()), tables(sub, os.getpid())
    assert main(["runs", "--json", "--subsystem", sub]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert sorted(row["table"] for row in rows) == sorted(f"/dev/shm{t.name}" for t in (first, second))
    assert {(row["subsystem"], row["pid"], row["answered"]) for row in rows} == {(sub, os.getpid(), False)}
    assert all(row["started_at"] and row["configuration"] is None for row in rows)  # no supervisor answers a fake run
    assert main(["runs", "--subsystem", sub]) == 0
    out = capsys.readouterr().out
    assert "live runs" in out and all(t.name.split(".")[2] in out for t in (first, second)) and "(no answer)" in out
    assert main(["runs", "--subsystem", "nosuch"]) == 0
    assert capsys.readouterr().out.startswith("no live run of 'nosuch' of yours")


def test_a_verb_without_run_among_several_runs_of_a_subsystem_lists_them_and_asks_for_run(tables, capsys):
    sub = new_subsystem()
    ids = sorted(t.name.split(".")[2] for t in (tables(sub, os.getpid()), tables(sub, os.getpid())))
    for verb in (["status"], ["stop"], ["svar"], ["on", "pid"], ["job", "move"], ["event", "goal", "1"]):
        assert main([*verb, "--subsystem", sub]) == 2
        err = capsys.readouterr().err.replace("\n", "")
        assert err.startswith(f"error: 2 runs of subsystem '{sub}' are alive: ")
        assert err.endswith("pass --run ID (pbo runs lists them)") and all(f"run {i} (pid" in err for i in ids)
    assert main(["svar", "q_m", "--run", ids[1]]) == 0
    assert f"{sub} · run {ids[1]}" in capsys.readouterr().out


# --- a second run of a subsystem with exclusive devices ------------------------------------------


def subsystem_file(directory: Path, subsystem: str, exclusive: bool) -> str:
    return str(subsystem_copy(directory, subsystem, exclusive))


def test_a_second_run_of_a_subsystem_whose_exclusive_device_is_in_use_is_refused_naming_the_run(tables, tmp_path):
    sub = new_subsystem()
    other = tables(sub, os.getpid())  # a live run of the subsystem (this process stands in for its supervisor)
    other_id = other.name.split(".")[2]
    with pytest.raises(RunRefused, match=rf"^subsystem '{sub}' is already running as run {other_id} \(pid {os.getpid()}, "
                                          rf"started [0-9:]+\), which holds its exclusive device\(s\) 'arm': a second run "
                                          rf"would drive them too; stop that run first: pbo stop --run {other_id}$"):
        Supervisor(load_subsystem(subsystem_file(tmp_path, sub, exclusive=True)), options=RunOptions(clock="sim"))


def test_a_second_run_of_a_subsystem_without_exclusive_devices_is_not_refused(tables, tmp_path):
    sub = new_subsystem()
    tables(sub, os.getpid())
    supervisor = Supervisor(load_subsystem(subsystem_file(tmp_path, sub, exclusive=False)), options=RunOptions(clock="sim"))
    assert supervisor.subsystem.name == sub


def test_a_run_that_finds_another_run_started_at_the_same_instant_refuses_and_leaves_nothing(tables, tmp_path):
    sub = new_subsystem()
    supervisor = Supervisor(load_subsystem(subsystem_file(tmp_path, sub, exclusive=True)), options=RunOptions(clock="sim"))
    other = tables(sub, os.getpid())  # appeared after the first check: the second one, with the table made, sees it
    with pytest.raises(RunRefused, match=rf"already running as run {other.name.split('.')[2]} "):
        supervisor.run()
    assert [o.name for o in shm.list_objects(sub)] == [other.name, f"{other.name}.lock"]  # none of the refused run's
    assert not supervisor.children, "no process was started"


# --- end to end: real runs ----------------------------------------------------------------------


def pbo(*arguments: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([*PBO, *arguments], capture_output=True, text=True, timeout=120, cwd=cwd)


class Runs:
    """`pbo run FILE --clock sim --duration 0` processes, each until it says its configuration is on; killed after the test."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.started: list[subprocess.Popen] = []

    def start(self, file: str) -> tuple[subprocess.Popen, str]:
        """The process and its run id, once it runs."""
        process = subprocess.Popen([*PBO, "run", file, "--clock", "sim", "--duration", "0", "--no-live"], cwd=self.directory,
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.started.append(process)
        said = read_until(process, "is on")
        assert "is on" in said, said + (process.stderr.read() if process.poll() is not None else "")
        return process, next(r.run_id for r in live_runs() if r.pid == process.pid)

    def stop_all(self) -> None:
        for process in self.started:
            if process.poll() is None:
                process.terminate()
                try:
                    process.communicate(timeout=60)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.communicate()


@pytest.fixture
def runs(tmp_path) -> Iterator[Runs]:
    made = Runs(tmp_path)
    yield made
    made.stop_all()


def stopped(process: subprocess.Popen) -> int:
    process.communicate(timeout=60)
    return process.returncode


@pytest.mark.multiprocess
def test_a_second_pbo_run_is_refused_before_it_starts_and_pbo_runs_and_run_pick_the_first(runs, tmp_path):
    sub = new_subsystem()
    file = subsystem_file(tmp_path, sub, exclusive=True)
    first, first_id = runs.start(file)
    refused = pbo("run", file, "--clock", "sim", "--duration", "0.05", "--no-live", cwd=tmp_path)
    assert refused.returncode == 2, refused.stdout + refused.stderr
    assert refused.stderr.startswith(f"error: subsystem '{sub}' is already running as run {first_id} (pid {first.pid}, ")
    assert "exclusive device(s) 'arm'" in refused.stderr and f"pbo stop --run {first_id}" in refused.stderr
    assert "starting subsystem" not in refused.stdout, "nothing started"
    assert {o.run_id for o in shm.list_objects(sub)} == {first_id}, "the refused run left nothing"
    listed = pbo("runs", "--json", "--subsystem", sub)
    assert listed.returncode == 0, listed.stderr
    [row] = json.loads(listed.stdout)
    assert (row["run_id"], row["pid"], row["configuration"], row["file"]) == (first_id, first.pid, "joint_pid", file)
    prefix = first_id[: first_id.index("-") + 2]
    status = pbo("status", "--run", prefix)
    assert status.returncode == 0 and f"{sub} · run {first_id}" in status.stdout, status.stderr
    assert pbo("stop", "--run", prefix).returncode == 0
    assert stopped(first) == 0


@pytest.mark.multiprocess
def test_two_runs_of_a_subsystem_without_exclusive_devices_run_side_by_side_and_run_picks_each(runs, tmp_path):
    sub = new_subsystem()
    file = subsystem_file(tmp_path, sub, exclusive=False)
    (first, first_id), (second, second_id) = runs.start(file), runs.start(file)
    ambiguous = pbo("status", "--subsystem", sub)
    assert ambiguous.returncode == 2
    assert ambiguous.stderr.startswith(f"error: 2 runs of subsystem '{sub}' are alive: '{sub}' run {first_id} (pid {first.pid}")
    assert f"'{sub}' run {second_id} (pid {second.pid}" in ambiguous.stderr and "pass --run ID" in ambiguous.stderr
    values = pbo("svar", "q_m", "--run", second_id)
    assert values.returncode == 0 and f"{sub} · run {second_id}" in values.stdout, values.stderr
    assert [row["run_id"] for row in json.loads(pbo("runs", "--json", "--subsystem", sub).stdout)] == [first_id, second_id]
    for process, identifier in ((first, first_id), (second, second_id)):
        assert pbo("stop", "--run", identifier).returncode == 0
        assert stopped(process) == 0


# --- end to end: another uid plants objects next to root's live run ------------------------------

def plant_as(uid: int, files: list[tuple[Path, int, bytes]]) -> None:
    """Create `files` (path, mode, bytes) from a forked child that drops to `uid` (no groups) first."""
    reader, writer = os.pipe()
    child = os.fork()
    if child == 0:  # the child: only system calls from here, then _exit (never back into pytest)
        status = 1
        try:
            os.close(reader)
            os.setgroups([])
            os.setgid(uid)
            os.setuid(uid)
            for path, mode, data in files:
                descriptor = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY | os.O_NOFOLLOW, 0o600)
                os.fchmod(descriptor, mode)  # whatever the umask
                os.write(descriptor, data)
                os.close(descriptor)
            os.write(writer, str(os.geteuid()).encode())
            status = 0
        except BaseException as exc:  # reported to the parent through the pipe
            os.write(writer, repr(exc).encode())
        finally:
            os._exit(status)
    os.close(writer)
    with os.fdopen(reader) as said:
        answer = said.read()
    _, status = os.waitpid(child, 0)
    assert os.waitstatus_to_exitcode(status) == 0 and answer == str(uid), answer


def run_objects(table: str) -> list[tuple[str, str]]:
    """Every object of a run: what its table's manifest names."""
    entries, _pids = read_run_manifest(table)
    return entries


@as_root
@pytest.mark.multiprocess
def test_objects_another_user_plants_change_nothing_for_roots_runs(runs, planted, tmp_path):
    victim, bystander = new_subsystem("victim"), new_subsystem("newrun")
    process, live_id = runs.start(subsystem_file(tmp_path, victim, exclusive=True))
    table = messages.table_name(victim, live_id)
    objects = run_objects(table)
    assert len(objects) >= 6 and all(exists(*o) for o in objects)
    # a dead run's table whose manifest names the live run's objects; tables named after pid 1 (alive for
    # ever); a segment anyone may write; for the live run's subsystem and for one about to start
    aimed = fake_table_bytes([f"{kind} {name}" for kind, name in objects])
    files = []
    for sub in (victim, bystander):
        files += [(planted.name(sub, NO_SUCH_PID, "table"), 0o600, aimed), (planted.name(sub, 1, "table"), 0o600, aimed),
                  (planted.name(sub, NO_SUCH_PID, "plant"), 0o666, bytes(64))]
    plant_as(NOBODY, [(shm.SHM_DIR / name.lstrip("/"), mode, data) for name, mode, data in files])
    assert {os.stat(path).st_uid for path in planted.paths} == {NOBODY}

    for sub in (victim, bystander):  # by subsystem: other test runs on this machine keep their own leftovers
        cleaned = pbo("clean", "--subsystem", sub)
        assert cleaned.returncode == 0, cleaned.stderr
        said = cleaned.stdout.replace("\n", "")
        assert said.startswith("removed 0 object(s) left by dead runs"), said
        assert "ignored 3 object(s) named like a run's but not yours to trust" in said
        assert all(name in said for name, _, _ in files if f".{sub}." in name), said
    assert all(exists(*o) for o in objects), "root's pbo clean left the live run whole"
    for verb in (["status"], ["svar", "q_m"]):
        answered = pbo(*verb, "--subsystem", victim)
        assert answered.returncode == 0 and f"{victim} · run {live_id}" in answered.stdout, answered.stderr
    assert [row["run_id"] for row in json.loads(pbo("runs", "--json", "--subsystem", victim).stdout)] == [live_id]
    new = pbo("run", subsystem_file(tmp_path, bystander, exclusive=True), "--clock", "sim", "--duration", "0.05",
              "--no-live", cwd=tmp_path)
    assert new.returncode == 0, new.stderr
    assert "left by a dead run" not in new.stdout
    assert all(exists(*o) for o in objects), "the new run's start-up cleanup left the live run whole"
    assert all(path.exists() for path in planted.paths), "nobody's objects were not touched"
    stop = pbo("stop", "--subsystem", victim)
    assert stop.returncode == 0, stop.stderr
    assert stopped(process) == 0
    assert not any(exists(*o) for o in objects), "the run removed its own objects as it stopped"
