"""The fork server: a child it forks is its starter's own, single-threaded, at SCHED_OTHER, dies with
its starter, and says how it ended; a server that cannot serve says so, and a run then starts fresh
interpreters and leaves nothing behind; a run with a restart policy keeps its server, restarts an
RTPU from it, and leaves nothing whether it ends or its supervisor is killed."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.ipc.process import DEATH_SIGNAL
from pbo_runtime.supervisor.fork_server import RUN_PRELOAD, ForkServer, ForkServerUnavailable
from pbo_runtime.supervisor.fork_server_process import PLANT_HOST
from pbo_runtime.supervisor.run_options import RunOptions
from pbo_runtime.supervisor.supervisor import Supervisor
from tests.support import (
    DEMO,
    PBO,
    REPO,
    assert_nothing_left,
    children_of,
    config_copy,
    demo_copy,
    ipc_names,
    read_until,
    run_processes,
    start_run,
    until,
)

PROBE = "tests.fork_probe"
SAFETY_NET = 60.0  # seconds for a process to go: a net for a hang, not a timing


@pytest.fixture
def server(monkeypatch):
    monkeypatch.setenv("PYTHONPATH", str(REPO))  # the server imports tests.fork_probe
    started = ForkServer.start(str(REPO / "configs" / "pid_joint.yaml"), [PROBE])
    yield started
    started.close()


def _gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as stream:
            return "zombie" in stream.read().lower()
    except FileNotFoundError:
        return True


@pytest.mark.multiprocess
@pytest.mark.parametrize("code", [0, 5])
def test_a_forked_child_is_its_starters_own_single_threaded_at_sched_other_and_says_how_it_ended(server, tmp_path, code):
    out = tmp_path / "said.json"
    child = server.fork(PROBE, [str(out), "report", str(code), "--parent", str(os.getpid())])
    assert child.wait(timeout=SAFETY_NET) == code
    said = json.loads(out.read_text())
    assert said["pid"] == child.pid and said["ppid"] == os.getpid()  # re-parented: reaped here, not by the server
    assert said["death_signal"] == DEATH_SIGNAL  # dies with its starter
    assert said["threads"] == 1 and said["scheduler"] == os.SCHED_OTHER
    assert said["openblas"] == os.environ.get("OPENBLAS_NUM_THREADS")  # the server's own setting given back
    assert f"-m {PROBE} {out} report" in said["cmdline"]  # its own command line, not the server's
    assert server.warm_at > 0
    assert "modules.pid_joint" in said["modules"]  # imported once, by the server


@pytest.mark.multiprocess
def test_children_forked_in_one_request_are_each_their_starters_own_and_end_as_each_was_told(server, tmp_path):
    outs = [tmp_path / f"said{index}.json" for index in range(3)]
    children = server.fork_all([(PROBE, [str(out), "report", str(index), "--parent", str(os.getpid())])
                                for index, out in enumerate(outs)])
    assert [child.wait(timeout=SAFETY_NET) for child in children] == [0, 1, 2]
    for child, out in zip(children, outs, strict=True):
        said = json.loads(out.read_text())
        assert said["pid"] == child.pid and said["ppid"] == os.getpid()
        assert f"-m {PROBE} {out} report" in said["cmdline"]


@pytest.mark.multiprocess
def test_a_request_naming_a_child_the_server_does_not_start_starts_none(server, tmp_path):
    out = tmp_path / "said.json"
    with pytest.raises(ForkServerUnavailable, match=r"^the fork server does not start 'tests.no_such_module'"):
        server.fork_all([(PROBE, [str(out), "report", "0", "--parent", str(os.getpid())]),
                         ("tests.no_such_module", ["--parent", str(os.getpid())])])
    assert not out.exists()
    assert not any(f"-m {PROBE}" in command for command in children_of(os.getpid()).values())


@pytest.mark.multiprocess
def test_a_child_that_fails_before_it_is_ready_ends_with_status_1(server, tmp_path):
    child = server.fork(PROBE, [str(tmp_path / "said.json"), "raise", "0", "--parent", str(os.getpid())])
    assert child.wait(timeout=SAFETY_NET) == 1
    assert child.poll() == 1


@pytest.mark.multiprocess
def test_a_dead_fork_server_is_unavailable(server, tmp_path):
    server.process.kill()
    server.process.wait()
    with pytest.raises(ForkServerUnavailable, match=r"^the fork server \(pid \d+\) (is gone|did not answer)"):
        server.fork(PROBE, [str(tmp_path / "said.json"), "report", "0", "--parent", str(os.getpid())])


@pytest.mark.multiprocess
def test_a_fork_server_that_cannot_import_what_it_runs_refuses_every_request(tmp_path):
    broken = ForkServer.start(str(REPO / "configs" / "pid_joint.yaml"), ["tests.no_such_module"])
    try:
        for _ in range(2):
            with pytest.raises(ForkServerUnavailable, match=r"^the fork server could not import .*ModuleNotFoundError"):
                broken.fork("tests.no_such_module", ["--parent", str(os.getpid())])
    finally:
        broken.close()
    assert broken.process.returncode == 0


@pytest.mark.multiprocess
def test_the_fork_servers_channel_is_a_socketpair_with_no_name(server):
    inode = os.fstat(server._channel.fileno()).st_ino  # type: ignore[union-attr]
    with open("/proc/net/unix", encoding="ascii") as stream:
        entries = [line.split() for line in stream.read().splitlines()[1:]]
    ours = [entry for entry in entries if entry[6] == str(inode)]
    assert ours and all(len(entry) == 7 for entry in ours)  # no path column: nobody else can connect


STARTER = """
import os, signal, sys
sys.path.insert(0, {repo!r})
from pbo_runtime.supervisor.fork_server import ForkServer
server = ForkServer.start({file!r}, [{probe!r}])
child = server.fork({probe!r}, [{out!r}, "sleep", "0", "--parent", str(os.getpid())])
print(server.process.pid, child.pid, flush=True)
signal.pause()
"""


@pytest.mark.multiprocess
def test_the_fork_server_and_a_child_it_forked_die_with_the_process_that_started_them(tmp_path):
    out = tmp_path / "said.json"
    code = STARTER.format(repo=str(REPO), file=str(REPO / "configs" / "pid_joint.yaml"), probe=PROBE, out=str(out))
    starter = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                               env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        assert starter.stdout is not None
        server_pid, child_pid = map(int, starter.stdout.readline().split())
        until(out.exists, "the child's report", SAFETY_NET)
        assert json.loads(out.read_text())["ppid"] == starter.pid
        starter.send_signal(signal.SIGKILL)
        starter.wait()
    finally:
        if starter.poll() is None:
            starter.kill()
            starter.wait()
    until(lambda: _gone(server_pid) and _gone(child_pid), "the server's and the child's end", SAFETY_NET)


@pytest.mark.multiprocess
def test_a_run_whose_fork_server_died_starts_fresh_interpreters_and_leaves_nothing(tmp_path):
    file = demo_copy(tmp_path, "fork_server_died")
    dead = ForkServer.start(str(file), ["pbo_runtime.supervisor.plant_host", "rtpu"])
    dead.process.kill()
    dead.process.wait()
    said: list[str] = []
    supervisor = Supervisor(load_subsystem(file), duration=0.05, say=said.append, fork_server=dead,
                            options=RunOptions(clock="sim", out_dir=str(tmp_path / "out")))
    result = supervisor.run()
    assert result.failure == "", result.failure
    assert any("fresh interpreters" in line for line in said), said
    assert result.startup["on"] >= result.startup["children"] >= result.startup["table"]
    assert_nothing_left(result.to_json())  # (every queue and segment it names, opened by name)


@pytest.mark.multiprocess
def test_a_run_forks_its_children_from_the_fork_server_and_leaves_nothing(tmp_path):
    file = demo_copy(tmp_path, "fork_server_run")
    said: list[str] = []
    supervisor = Supervisor(load_subsystem(file), duration=0.05, say=said.append,
                            options=RunOptions(clock="sim", out_dir=str(tmp_path / "out")))
    result = supervisor.run()
    assert result.failure == "", result.failure
    assert not any("fresh interpreters" in line for line in said), said
    assert "fork_server" in result.startup  # the server was warm when the children were forked
    assert supervisor.processes.fork_server is None  # ended with the run
    assert_nothing_left(result.to_json())  # (every queue and segment it names, opened by name)


@pytest.mark.multiprocess
@pytest.mark.parametrize("ending", ["ctrl-c", "supervisor killed"])
def test_a_run_with_a_restart_policy_keeps_its_fork_server_restarts_from_it_and_leaves_nothing(tmp_path, ending):
    name = f"fork_kept_{ending.split()[0].replace('-', '_')}"
    config = config_copy(DEMO, tmp_path, name, (("rtpus: [rtpu0, rtpu1]",
                                                 "rtpus: [rtpu0, rtpu1]\nrestart: {max: 3, within: 10 min}"),))
    report_path = tmp_path / "report.json"
    run = start_run(config, tmp_path, "--duration", "0", "--report", str(report_path), "--out", str(tmp_path / "out"))
    try:
        kept = [pid for pid, command in children_of(run.pid).items() if "pbo_runtime.supervisor.fork_server" in command]
        assert len(kept) == 1, children_of(run.pid)  # kept once the children are up: an RTPU may be restarted
        os.kill(run_processes(run)["rtpu0"], signal.SIGKILL)
        said = read_until(run, "restarted:")
        assert "fresh interpreter" not in said, said  # the new rtpu0 was forked from the kept server
        children = list(children_of(run.pid))
        table = next(n for n in os.listdir("/dev/shm") if f"pbo.{name}.{run.pid}-" in n)
        run.send_signal(signal.SIGINT if ending == "ctrl-c" else signal.SIGKILL)
        out, err = run.communicate(timeout=SAFETY_NET)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    until(lambda: all(_gone(pid) for pid in children), "the fork server's and the children's end", SAFETY_NET)
    if ending == "ctrl-c":
        assert "fresh interpreter" not in out + err, err
        assert_nothing_left(json.loads(report_path.read_text()))
    else:  # the server and the children died with the supervisor, and the last of them out removed the run
        until(lambda: ipc_names(table.split(".")[2]) == [], "the run's objects removed", SAFETY_NET)
        assert "Traceback" not in out + err, err
    assert ipc_names(name) == []


def _servers_of(pid: int) -> list[int]:
    """The live fork servers whose supervisor was process `pid` (none once it has ended well)."""
    found = []
    for entry in os.listdir("/proc"):
        try:
            command = (Path("/proc") / entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, ValueError):
            continue
        if "pbo_runtime.supervisor.fork_server" in command and f"--parent {pid} " in command:
            found.append(int(entry))
    return found


@pytest.mark.multiprocess
@pytest.mark.parametrize("refused", ["a wrong argument", "a file with errors"])
def test_a_run_refused_before_it_starts_leaves_no_fork_server_behind(tmp_path, refused):
    file = demo_copy(tmp_path, "fork_refused")
    arguments = ["--durration", "1"] if refused == "a wrong argument" else ["--no-live"]
    if refused == "a file with errors":
        file.write_text(file.read_text().replace("period: 1 ms", "period: -1 ms", 1))
    pbo = subprocess.Popen([*PBO, "run", str(file), *arguments], cwd=tmp_path, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    _out, err = pbo.communicate(timeout=SAFETY_NET)
    assert pbo.returncode == 1, err
    assert "Traceback" not in err
    assert _servers_of(pbo.pid) == []  # forked before the arguments were parsed, and ended with the refusal


class _UnpicklableSubsystem:
    """Stands in for a subsystem that holds what cannot be pickled (a unit test's fake): the server loads its file."""

    file = str(DEMO)

    def __reduce__(self):
        raise TypeError("cannot be pickled")


@pytest.mark.multiprocess
@pytest.mark.parametrize("handed", ["the loaded subsystem", "a subsystem that cannot be pickled"])
def test_a_server_started_without_a_file_serves_once_handed_its_run(tmp_path, monkeypatch, handed):
    monkeypatch.setenv("PYTHONPATH", str(REPO))  # the server imports tests.fork_probe
    started = ForkServer.start(None, [PROBE])
    try:
        subsystem = load_subsystem(str(DEMO)) if handed == "the loaded subsystem" else _UnpicklableSubsystem()
        started.hand_over(subsystem)
        out = tmp_path / "said.json"
        child = started.fork(PROBE, [str(out), "report", "0", "--parent", str(os.getpid())])
        assert child.wait(timeout=SAFETY_NET) == 0
        assert json.loads(out.read_text())["ppid"] == os.getpid()
    finally:
        started.close()


# --- the plant's middle process, forked early (`fork_server_process.EarlyPlant`) --------------------


def _early_middle(server: ForkServer) -> int | None:
    """The pid of the server's early middle process for the plant, while it lives."""
    return next((pid for pid, command in children_of(server.process.pid).items() if "--early" in command.split()), None)


@pytest.fixture
def run_server():
    """A server as `pbo run` starts one: no file yet, preloading what its plant and its RTPUs run."""
    started = ForkServer.start(None, list(RUN_PRELOAD))
    until(lambda: _early_middle(started) is not None, "the server forks the plant's middle process")
    yield started
    started.close()


def _refused_arguments(module: str) -> tuple[str, list[str]]:
    """A child that ends at once with argparse's status 2, having said nothing but its usage."""
    return module, ["--no-such-argument", "--parent", str(os.getpid())]


@pytest.mark.multiprocess
def test_a_run_servers_plant_is_forked_by_its_early_middle_process_and_is_the_starters_own(run_server):
    run_server.hand_over(load_subsystem(str(DEMO)))
    plant, rtpu = run_server.fork_all([_refused_arguments(PLANT_HOST), _refused_arguments("rtpu")])
    assert plant.wait(timeout=SAFETY_NET) == 2  # waited for here: each is this process's child
    assert rtpu.wait(timeout=SAFETY_NET) == 2
    assert _early_middle(run_server) is None  # asked, it forked the plant and exited


@pytest.mark.multiprocess
def test_a_plant_whose_early_middle_process_died_is_forked_by_the_server_itself(run_server):
    early = _early_middle(run_server)
    assert early is not None
    os.kill(early, signal.SIGKILL)
    run_server.hand_over(load_subsystem(str(DEMO)))
    [plant] = run_server.fork_all([_refused_arguments(PLANT_HOST)])
    assert plant.wait(timeout=SAFETY_NET) == 2
    assert _early_middle(run_server) is None


@pytest.mark.multiprocess
def test_a_run_without_a_plant_ends_the_early_middle_process_once_handed_over(run_server):
    run_server.hand_over(dataclasses.replace(load_subsystem(str(DEMO)), plant=None))  # (its robot is hardware)
    until(lambda: _early_middle(run_server) is None, "the early middle process ends")
    [rtpu] = run_server.fork_all([_refused_arguments("rtpu")])
    assert rtpu.wait(timeout=SAFETY_NET) == 2


@pytest.mark.multiprocess
def test_a_run_server_ended_before_its_run_leaves_no_early_middle_process(run_server):
    early = _early_middle(run_server)
    assert early is not None
    run_server.close()  # (killed while it imports: the middle process dies with it)
    until(lambda: _gone(early), "the early middle process ends with its server", SAFETY_NET)
