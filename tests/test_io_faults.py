"""OS limits and I/O failures (issue 18, items 7 and 8): each ends in one line naming the limit or the path,
the OS error and the fix, a non-zero exit status, the summary printed, no traceback, nothing left behind.

Limits are lowered for one child only: `prlimit` for RLIMIT_MSGQUEUE and RLIMIT_NOFILE, a private IPC
namespace (`unshare -i`) for fs.mqueue's sysctls, a private mount namespace with a 16 KiB /dev/shm for
a full /dev/shm. A full disk is a small tmpfs (`small_disk`), or /dev/full: root ignores permissions,
so a read-only directory would prove nothing.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
from pathlib import Path

import mujoco
import numpy as np
import posix_ipc
import pytest

from drivers.mujoco_arm.plant import MujocoArmPlant
from pbo_runtime import open_log, read_log
from pbo_runtime.cli.main import main
from pbo_runtime.cli.output_paths import OutputPathError, write_report
from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.ipc import messages
from pbo_runtime.ipc.limits import KERNEL_BYTES_PER_MESSAGE
from pbo_runtime.reports.data_log import LogError
from pbo_runtime.supervisor.supervisor import Supervisor
from tests.support import DEMO, NO_WATCHDOG, PBO, assert_nothing_left, children_of, demo_copy, fill_disk, unique_name, until

PID_JOINT_QUEUE_BYTES = 51_872  # docs/architecture.md: 50.7 KiB (275.6 KiB when every queue was 10 x 8 KiB)


def run_limited(tmp_path: Path, wrapper: list[str], *arguments: str) -> tuple[subprocess.CompletedProcess, dict]:
    """`pbo run` of the demo under `wrapper` (a command that lowers a limit, then runs the rest); its report."""
    report = tmp_path / "report.json"
    command = [*wrapper, *PBO, "run", str(DEMO), "--clock", "sim", "--duration", "0.1", "--no-live", "--report", str(report),
               *arguments]
    done = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=240)
    return done, json.loads(report.read_text())


def in_namespace(kind: str, script: str) -> list[str]:
    """A wrapper: a private namespace (-i: IPC, -m: mounts) where `script` runs first, then the command."""
    return ["unshare", kind, "sh", "-c", f'{script} && exec "$0" "$@"']


def assert_one_line_error(done: subprocess.CompletedProcess, pattern: str) -> None:
    """Exit status 2, the summary printed, no traceback, and the last line of stderr is the error."""
    assert done.returncode == 2, done.stdout + done.stderr
    assert "Traceback" not in done.stdout + done.stderr
    assert "run summary" in done.stdout
    assert re.fullmatch(pattern, done.stderr.strip().splitlines()[-1]), done.stderr


# --- OS limits -----------------------------------------------------------------------------------


@pytest.mark.multiprocess
@pytest.mark.parametrize(("wrapper", "pattern"), [
    pytest.param(["prlimit", "--msgqueue=20000"],
                 r"error: this run needs 50\.7 KiB of POSIX message-queue memory \(4 queues\), more than the per-user "
                 r"limit RLIMIT_MSGQUEUE of 19\.5 KiB: raise it \(ulimit -q 1000000\) and run again", id="queue memory"),
    pytest.param(in_namespace("-i", "echo 2 > /proc/sys/fs/mqueue/queues_max"),
                 r"error: this run needs 4 POSIX message queues and the system allows fs\.mqueue\.queues_max = 2(, \d+ "
                 r"are in use)?: stop other runs \(pbo runs\) or raise it \(sysctl fs\.mqueue\.queues_max=\d+\)",
                 id="number of queues"),
    pytest.param(in_namespace("-i", "echo 1024 > /proc/sys/fs/mqueue/msgsize_max"),
                 r"error: queue /pbo\.puma\.[\w-]+\.events needs messages of 2048 bytes, more than fs\.mqueue\.msgsize_max "
                 r"= 1024: raise it \(sysctl fs\.mqueue\.msgsize_max=8192\) and run again", id="message size"),
    pytest.param(in_namespace("-m", "mount -t tmpfs -o size=16k tmpfs /dev/shm"),
                 r"error: [^:]+: /dev/shm is full \((this needs [\d.]+ KiB; )?[\d.]+ KiB free of 16\.0 KiB\): remove what "
                 r"dead runs left \(pbo clean\), stop other runs \(pbo runs\), or enlarge it \(mount -o remount,size=1G "
                 r"/dev/shm\)", id="/dev/shm full"),
    pytest.param(["prlimit", "--nofile=10"],
                 r"error: [^:]+: too many open files: this process has all that RLIMIT_NOFILE \(ulimit -n\) allows, 10, "
                 r"open; raise it \(ulimit -n 1024\)", id="open files"),
])
def test_an_os_limit_ends_the_run_with_one_line_naming_it_and_the_fix(tmp_path, wrapper, pattern):
    if wrapper[0] == "unshare" and subprocess.run(["unshare", wrapper[1], "true"], capture_output=True).returncode != 0:
        pytest.skip("no private namespaces here")
    done, report = run_limited(tmp_path, wrapper)
    assert_one_line_error(done, pattern)
    assert report["stopped_by"] == "failure"
    assert_nothing_left(report)


@pytest.mark.multiprocess
def test_queue_memory_taken_by_other_queues_is_named_at_the_queue_that_did_not_fit(tmp_path):
    # Other queues of this user (here one the test holds; on a shared machine others' runs too) take
    # more than the room left above what the run needs: the pre-check passes, a creation fails.
    hog = posix_ipc.MessageQueue(unique_name("hog"), posix_ipc.O_CREX, mode=0o600, max_messages=10, max_message_size=512)
    try:
        done, report = run_limited(tmp_path, ["prlimit", f"--msgqueue={PID_JOINT_QUEUE_BYTES + 2000}"])
    finally:
        hog.close()
        hog.unlink()
    assert_one_line_error(
        done, r"error: creating queue /pbo\.puma\.[\w-]+\.\w+(-\w+)?: the per-user POSIX message-queue memory RLIMIT_MSGQUEUE "
              r"\(52\.6 KiB\) is used up: this run needs 50\.7 KiB and other queues of this user hold the rest; stop other "
              r"runs \(pbo runs\) or raise it \(ulimit -q \d+\)")
    assert_nothing_left(report)


def test_a_run_of_the_demo_needs_the_queue_memory_the_docs_give():
    plan = Supervisor(load_subsystem(str(DEMO)), duration=0.1).queue_plan()
    assert [(q.name.rsplit(".", 1)[1], q.depth, q.message_bytes) for q in plan] == [
        ("events", 10, 2048), ("rtpu-rtpu0", 10, 168), ("rtpu-rtpu1", 10, 168), ("control", 6, 4096)]
    assert sum(q.bytes for q in plan) == sum(q.depth * (q.message_bytes + KERNEL_BYTES_PER_MESSAGE) for q in plan)
    assert sum(q.bytes for q in plan) == PID_JOINT_QUEUE_BYTES


def test_the_event_queue_grows_for_a_switch_of_many_tasks_up_to_the_systems_message_size():
    assert messages.event_queue_size("", [["pid"] * 10, ["robot"]]).message_bytes == messages.EVENT_BYTES
    assert messages.event_queue_size("", [[f"task_{i:04d}" for i in range(200)]]).message_bytes == 256 + 2 * 200 * 11
    assert messages.event_queue_size("", [[f"task_{i:04d}" for i in range(2000)]]).message_bytes == messages.MESSAGE_BYTES


def test_an_event_too_long_for_its_queue_arrives_with_its_long_strings_cut():
    queue = messages.Queue(unique_name("events"), create=True, size=messages.event_queue_size("", [["pid"]]))
    try:
        assert queue.report("rtpu0", messages.StateChanged("pid", "ERROR", "cycle raised ValueError: " + "x" * 10_000))
        source, event = queue.receive_event(0)
    finally:
        queue.close()
    assert source == "rtpu0" and isinstance(event, messages.StateChanged)
    assert event.error.startswith("cycle raised ValueError: xxx") and "characters cut...]" in event.error
    assert len(event.error) < 1100


def test_a_signal_too_long_for_its_queue_is_refused_not_cut():
    queue = messages.Queue(unique_name("signals"), create=True, size=messages.signal_queue_size("", ["goal"]))
    try:
        with pytest.raises(messages.InternalError, match=r"^a 'event' message of \d+ B does not fit queue "):
            queue.signal(messages.OperatorEvent("goal", [0.5] * 100))
    finally:
        queue.close()


# --- output paths, checked before anything starts ----------------------------------------------


@pytest.mark.parametrize(("arguments", "pattern"), [
    (["--out", "/proc/pbo-out"], r"error: --out /proc/pbo-out: is under /proc, the kernel's own files, not a place for a "
                                 r"run's results; name a directory on a disk, e\.g\. runs/"),
    (["--out", "/sys/pbo"], r"error: --out /sys/pbo: is under /sys, .*"),
    (["--report", "/proc/self/report.json"], r"error: --report /proc/self/report\.json: is under /proc, .*"),
    (["--report", "/dev/full"], r"error: --report /dev/full: refuses writes: \[Errno 28\] No space left on device; name a "
                                r"file on a disk"),
    (["--out", "/dev/full/x"], r"error: --out /dev/full/x: cannot make the directory: \[Errno 20\] Not a directory; a part "
                               r"of the path is a file, not a directory"),
    (["--report", "{tmp}"], r"error: --report \S+: is a directory; name a file \(or use --out DIR for DIR/report\.json\)"),
    (["--out", "{tmp}/a-file"], r"error: --out \S+/a-file: exists and is not a directory; name a directory \(it is made if "
                                r"missing\)"),
])
@pytest.mark.parametrize("file", [DEMO, DEMO.parent / "leader_follower.yaml"], ids=["subsystem", "application"])
def test_an_output_path_that_cannot_take_the_results_is_refused_before_the_run_starts(tmp_path, capsys, arguments, pattern,
                                                                                      file):
    (tmp_path / "a-file").write_text("")
    arguments = [a.replace("{tmp}", str(tmp_path)) for a in arguments]
    assert main(["run", str(file), "--clock", "sim", "--no-live", *arguments]) == 1
    out, err = capsys.readouterr()
    assert "starting" not in out  # nothing started
    assert re.fullmatch(pattern, err.strip()), err


@pytest.mark.parametrize("option", ["--out", "--report"])
def test_an_output_path_on_a_full_disk_is_refused_before_the_run_starts(small_disk, capsys, option):
    fill_disk(small_disk)
    target = small_disk / ("run" if option == "--out" else "report.json")
    assert main(["run", str(DEMO), "--clock", "sim", "--no-live", option, str(target)]) == 1
    _, err = capsys.readouterr()
    assert re.fullmatch(rf"error: {option} \S+: cannot (create a file|write) in \S+: \[Errno 28\] No space left on device; "
                        r"free space on that file system \(df -h shows it\) or name another place", err.strip()), err
    assert sorted(p.name for p in small_disk.iterdir()) == ["filler"] + (["run"] if option == "--out" else [])


def test_a_report_that_cannot_be_written_leaves_the_previous_one_whole_and_no_temporary_file(small_disk):
    report = small_disk / "report.json"
    report.write_text('{"previous": true}')
    fill_disk(small_disk)
    with pytest.raises(OutputPathError, match=r"^cannot write the run report \S+/report\.json: \[Errno 28\] No space left "
                                              r"on device; free space on that file system"):
        write_report(report, json.dumps({"big": "x" * 100_000}))
    assert json.loads(report.read_text()) == {"previous": True}
    assert sorted(p.name for p in small_disk.iterdir()) == ["filler", "report.json"]


def test_a_report_to_a_device_is_written_in_place(tmp_path):
    write_report(Path("/dev/null"), "{}")  # no temporary file beside /dev/null, and /dev/null stays a device
    assert Path("/dev/null").is_char_device()


# --- a disk that fills during the run --------------------------------------------------------------


@pytest.mark.multiprocess
def test_a_disk_that_fills_during_the_run_fails_the_log_and_the_report_with_the_summary_printed(tmp_path, small_disk):
    fill_disk(small_disk, leave=4096)  # one page: the --out probe takes it and gives it back; the log's header then takes it
    report = tmp_path / "elsewhere" / "report.json"
    npy = demo_copy(tmp_path, "puma", logger={"params": {"variables": ["q_m", "q_r", "tau_u"], "path": "pid_joint.npy"}})
    done = subprocess.run([*PBO, "run", str(npy), "--clock", "sim", "--duration", "1.5", "--no-live", "--out", str(small_disk),
                           "--report", str(report)], cwd=tmp_path, capture_output=True, text=True, timeout=240)
    assert done.returncode == 2, done.stdout + done.stderr
    assert "Traceback" not in done.stdout + done.stderr
    assert "run summary: puma" in done.stdout and "(stopped by duration)" in done.stdout
    errors = done.stderr.strip().splitlines()
    said = " ".join(done.stdout.split())  # as the operator read it, unwrapped
    assert re.search(r"pbo: task 'logger' on rtpu0 is in ERROR: cycle raised OutputError: cannot write log \S+/pid_joint\.npy "
                     r"\(100 rows after the 0 written\): \[Errno 28\] No space left on device at data_logger\.py:\d+", said)
    assert re.fullmatch(r"fault: task 'logger' on rtpu0 could not write its output: cycle raised OutputError: cannot write "
                        r"log \S+/pid_joint\.npy \(100 rows after the 0 written\): \[Errno 28\] No space left on device at "
                        r"data_logger\.py:\d+.*", errors[-3]), done.stderr
    # the logger is part of the configuration: the robot held the arm from its error to the stop, and says so
    assert errors[-2].startswith("fault: critical task 'robot' ran its locally stable behaviour until the stop"), done.stderr
    assert re.fullmatch(r"error: cannot write the run report \S+/report\.json: \[Errno 28\] No space left on device; free "
                        r"space on that file system \(df -h shows it\) or name another place", errors[-1]), done.stderr
    assert sorted(p.name for p in small_disk.iterdir()) == ["filler", "pid_joint.npy"]  # no report.json, no temporary file
    assert len(np.load(small_disk / "pid_joint.npy")) == 0  # the header alone: a valid, empty log
    written = json.loads(report.read_text())  # the report that could be written has it all
    assert written["faults"] == [line.removeprefix("fault: ") for line in errors[-3:-1]]
    assert written["queue_bytes"] == PID_JOINT_QUEUE_BYTES
    assert_nothing_left(written)


# --- a killed RTPU loses at most the chunk its logger was filling --------------------------------


@pytest.mark.multiprocess
@pytest.mark.parametrize("name", ["pid_joint.mcap", "pid_joint.npy"])
def test_a_sigkill_of_the_loggers_rtpu_loses_at_most_the_chunk_it_was_filling(tmp_path, name):
    """The log, MCAP or .npy, reads back with every row of the chunks written before the kill (issue 21)."""
    out, report = tmp_path / "out", tmp_path / "report.json"
    config = demo_copy(tmp_path, f"kill_{name.split('.')[1]}",
                       logger={"params": {"variables": ["q_m", "q_r", "tau_u"], "path": name}})
    run = subprocess.Popen([*PBO, "run", str(config), "--clock", "sim", "--duration", "0", "--no-live", "--out", str(out),
                            "--report", str(report)], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    log = out / name
    try:
        until(lambda: rows_in(log) >= 200, "two chunks of the log written", safety_net=120)
        seen = rows_in(log)
        rtpu0 = next(pid for pid, command in children_of(run.pid).items() if "--rtpu rtpu0" in command)
        os.kill(rtpu0, signal.SIGKILL)
        stdout, stderr = run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    assert run.returncode == 2 and "Traceback" not in stdout + stderr
    assert re.search(r"error: RTPU 'rtpu0' \(pid \d+\) died \(killed by SIGKILL\) while hosting tasks: traj, pid, logger", stderr)
    result = json.loads(report.read_text())
    rows = read_log(log)
    taken = round(result["duration"] / 0.01) + 1  # the logger's cycles, every 10 ms from 0 to the death
    assert seen <= len(rows)
    # Lost: the chunk it was filling, and the rows taken while the writer thread wrote the last one
    # handed over (milliseconds of wall time: a tick or two of the simulated clock; 20 is the margin).
    assert taken - len(rows) <= 100 + 20, (taken, len(rows))
    np.testing.assert_allclose(rows["time"], np.arange(len(rows)) * 0.01, atol=1e-9)  # none missing on the way
    assert sorted(p.name for p in out.iterdir()) == [name, "report.json"]
    assert_nothing_left(result)
    if name.endswith(".mcap"):
        kept = open_log(log)
        assert not kept.complete and kept.units["q_m"] == "rad"  # no summary: read chunk by chunk, units and all


def rows_in(log: Path) -> int:
    """The rows a log holds now (0 before its header is written: it is created empty, then written)."""
    try:
        return len(read_log(log))
    except (OSError, EOFError, ValueError, LogError):
        return 0


# --- MuJoCo's log --------------------------------------------------------------------------------


@pytest.fixture
def mujoco_warnings_restored():
    previous = mujoco.get_mju_user_warning()
    yield
    mujoco.set_mju_user_warning(previous)


def test_mujocos_warnings_go_to_the_runs_output_directory_not_the_working_directory(tmp_path, monkeypatch, capsys,
                                                                                   mujoco_warnings_restored):
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    plant = MujocoArmPlant(unique_name("plant"), "puma560", 0.001, NO_WATCHDOG, log_dir=str(out))
    try:
        plant.data.qfrc_applied[0] = np.nan
        mujoco.mj_step(plant.model, plant.data)
    finally:
        plant.close()
    assert "Nan, Inf or huge value in QACC" in (out / "MUJOCO_LOG.TXT").read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert "plant: MuJoCo warning: Nan, Inf or huge value in QACC" in capsys.readouterr().err
