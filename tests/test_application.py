"""Applications of several subsystems (TR §5): the file's checks, and two arms joined by a link."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import posix_ipc
import pytest

from pbo_runtime import read_log
from pbo_runtime.config.application import check_application
from pbo_runtime.config.file_kind import is_application_file
from tests.support import PBO, REPO, assert_ended_well, assert_nothing_left, children_of

APP = REPO / "configs" / "leader_follower.yaml"


SHIPPED_LINKS = ("  arm_state: {type: float64, shape: [6], transport: shm}\n"
                 "  goal: {kind: message, type: float64, shape: [6], capacity: 4, transport: shm}\n")


def write_app(tmp_path, links: str = SHIPPED_LINKS, follower: str | None = None, leader: str | None = None,
              operator: str | None = None, run: str = "run:\n  operator: {app: tour}\n") -> str:
    """The shipped application, copied beside its subsystems so each part can be changed."""
    (tmp_path / "leader.yaml").write_text(leader or (REPO / "configs" / "leader.yaml").read_text())
    (tmp_path / "follower.yaml").write_text(follower or (REPO / "configs" / "follower.yaml").read_text())
    text = APP.read_text()
    head, inline = text[:text.index("  operator:")], text[text.index("  operator:"):text.index("links:\n")]
    path = tmp_path / "app.yaml"
    path.write_text(head.replace("application: leader_follower", "application: pair") + (operator or inline)
                    + "links:\n" + links + run)
    return str(path)


def codes(result) -> list[str]:
    return [e.code for e in result.errors]


def test_the_shipped_application_checks_clean_and_names_each_link_end():
    result = check_application(APP)
    assert result.ok, [e.format() for e in result.errors]
    link = result.application.links["arm_state"]
    assert (link.sender, link.receiver) == (("leader", "send"), ("follower", "receive"))
    assert is_application_file(APP) and not is_application_file(REPO / "configs" / "leader.yaml")


def test_a_task_naming_an_undeclared_link_is_located_on_the_task(tmp_path):
    follower = (REPO / "configs" / "follower.yaml").read_text().replace("params: {link: arm_state}", "params: {link: arm_stat}")
    result = check_application(write_app(tmp_path, follower=follower))
    assert "E804" in codes(result)
    error = next(e for e in result.errors if e.code == "E804")
    assert error.file.endswith("follower.yaml") and error.line > 0
    assert "uses link 'arm_stat', which the application does not declare" in error.message


def test_a_link_without_a_receiver_is_an_error_with_a_hint(tmp_path):
    path = write_app(tmp_path, links=SHIPPED_LINKS + "  spare: {type: float64, shape: [6]}\n")
    result = check_application(path)
    assert codes(result) == ["E805", "E805"]
    assert {e.message for e in result.errors} == {"link 'spare' has no link_sender task",
                                                  "link 'spare' has no link_receiver task"}
    spare_line = Path(path).read_text().splitlines().index("  spare: {type: float64, shape: [6]}") + 1
    assert all(e.line == spare_line for e in result.errors)
    assert "module: link_receiver" in result.errors[1].hint + result.errors[0].hint


def test_a_variable_of_another_shape_than_its_link_is_refused(tmp_path):
    result = check_application(write_app(tmp_path, links=SHIPPED_LINKS.replace("shape: [6], transport: shm}",
                                                                               "shape: [7], transport: shm}")))
    assert codes(result).count("E806") == 2
    assert "carries float64 [7]" in result.errors[0].message


def test_an_unknown_transport_and_a_missing_subsystem_file_are_reported_together(tmp_path):
    path = write_app(tmp_path, links=SHIPPED_LINKS.replace("[6], transport: shm}", "[6], transport: carrier-pigeon}"))
    text = Path(path).read_text().replace("follower: follower.yaml", "follower: nowhere.yaml")
    Path(path).write_text(text)
    result = check_application(path)
    assert set(codes(result)) == {"E802", "E803"}
    assert any("unknown transport 'carrier-pigeon'" in e.message and "shm, zenoh" in e.hint for e in result.errors)
    assert any("no file 'nowhere.yaml'" in e.message for e in result.errors)


def test_an_error_in_a_subsystem_file_is_reported_with_its_own_location(tmp_path):
    follower = (REPO / "configs" / "follower.yaml").read_text().replace("period: 2 ms, params: {link",
                                                                        "period: 2 fortnights, params: {link")
    result = check_application(write_app(tmp_path, follower=follower))
    assert result.errors and all(e.file.endswith("follower.yaml") for e in result.errors)


@pytest.mark.multiprocess
def test_pbo_check_on_an_application_prints_every_link(tmp_path):
    done = subprocess.run([*PBO, "check", str(APP)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "link arm_state: leader.send -> follower.receive (float64 [6], periodic, shm)" in done.stdout
    assert "link goal: operator.console -> leader.goal (float64 [6], messages, 4 queued at most, shm)" in done.stdout
    assert "subsystem operator: " + str(APP) + "#operator ('operator', 2 task(s), runs application 'tour')" in done.stdout


def test_an_inline_subsystem_is_checked_in_full_and_its_errors_point_into_the_application_file(tmp_path):
    path = write_app(tmp_path)
    text = Path(path).read_text().replace("period: 10 ms, params: {link: goal}", "period: 10 weeks, params: {link: goal}")
    Path(path).write_text(text)
    result = check_application(path)
    assert result.errors and all(e.file == path for e in result.errors)
    error = result.errors[0]
    assert error.line == text.splitlines().index(next(line for line in text.splitlines() if "10 weeks" in line)) + 1
    assert "weeks" in error.message


def test_an_inline_subsystem_runs_under_its_reference_and_loads_alone(tmp_path):
    from pbo_runtime.config.loader import load_subsystem

    result = check_application(write_app(tmp_path))
    operator = result.application.subsystems["operator"]
    assert operator.file.endswith("app.yaml#operator") and operator.plant is None
    assert load_subsystem(operator.file).tasks.keys() == {"console", "logger"}  # what `pbo run` and each RTPU do


def test_a_missing_inline_subsystem_reference_is_a_clear_error(tmp_path):
    from pbo_runtime.config.loader import check_file

    result = check_file(write_app(tmp_path) + "#nobody")
    assert result.subsystem is None and "no inline subsystem 'nobody' under subsystems:" in result.errors[0].message


def test_a_message_sender_on_a_periodic_link_is_refused_with_the_fitting_modules(tmp_path):
    result = check_application(write_app(tmp_path,
                                         links=SHIPPED_LINKS.replace("kind: message, ", "").replace("capacity: 4, ", "")))
    errors = [e for e in result.errors if e.code == "E808"]
    assert len(errors) == 2 and codes(result) == ["E808", "E808"]  # the operator's sender and the leader's server
    periodic = "is a message_sender, a message link's end, but link 'goal' is a periodic link"
    assert periodic in errors[1].message + errors[0].message
    assert "kind: message" in errors[0].hint


def test_a_periodic_message_server_is_refused_with_how_to_make_it_aperiodic(tmp_path):
    leader = (REPO / "configs" / "leader.yaml").read_text().replace("aperiodic: true, min_interarrival: 10 ms,", "period: 10 ms,")
    result = check_application(write_app(tmp_path, leader=leader))
    assert codes(result) == ["E808"]
    assert "serves message link 'goal' but is periodic" in result.errors[0].message
    assert "aperiodic: true" in result.errors[0].hint and result.errors[0].file.endswith("leader.yaml")


@pytest.mark.parametrize("capacity, wanted", [("0", "from 1 to"), ("many", "from 1 to"), ("100000", "fs.mqueue.msg_max")])
def test_a_message_link_capacity_must_fit_the_systems_queues(tmp_path, capacity, wanted):
    result = check_application(write_app(tmp_path, links=SHIPPED_LINKS.replace("capacity: 4", f"capacity: {capacity}")))
    assert codes(result) == ["E803"]
    assert wanted in result.errors[0].message + result.errors[0].hint


def test_a_periodic_link_takes_no_capacity(tmp_path):
    links = SHIPPED_LINKS.replace("shape: [6], transport: shm}", "shape: [6], capacity: 3, transport: shm}", 1)
    result = check_application(write_app(tmp_path, links=links))
    assert codes(result) == ["E803"] and "is periodic and takes no capacity" in result.errors[0].message


def test_a_message_too_large_for_a_queue_is_sent_to_a_periodic_link_instead(tmp_path):
    links = SHIPPED_LINKS + "  image: {kind: message, type: float64, shape: [480, 640]}\n"
    result = check_application(write_app(tmp_path, links=links))
    error = next(e for e in result.errors if e.code == "E803")
    assert "more than the" in error.message and "kind: periodic" in error.hint


@pytest.mark.parametrize("run, wanted", [
    ("run:\n  nobody: {app: tour}\n", "run: no subsystem 'nobody'"),
    ("run:\n  operator: {app: grand_tour}\n", "has no application 'grand_tour'"),
    ("run:\n  operator: {config: operate, app: tour}\n", "not both"),
    ("run:\n  operator: {speed: 2}\n", "unknown option 'speed'"),
    ("run: 3\n", "run must map subsystems"),  # (a list is stages: tests/test_parallel_stages.py)
])
def test_the_run_section_names_a_subsystem_and_one_of_its_configurations_or_applications(tmp_path, run, wanted):
    result = check_application(write_app(tmp_path, run=run))
    assert codes(result) == ["E807"], [e.format() for e in result.errors]
    assert wanted in result.errors[0].message


def test_the_run_section_refuses_an_incomplete_application_as_pbo_run_would(tmp_path):
    inline = APP.read_text()
    inline = inline[inline.index("  operator:"):inline.index("links:\n")]
    operator = inline.replace("    applications:\n", "    applications:\n      loose: [aim]\n", 1)
    result = check_application(write_app(tmp_path, operator=operator, run="run:\n  operator: {app: loose}\n"))
    assert codes(result) == ["E807"], [e.format() for e in result.errors]
    error = result.errors[0]
    assert "application 'loose' of subsystem 'operator' is incomplete" in error.message
    assert error.line == len(Path(error.file).read_text().splitlines()) and "tour" in error.hint


@pytest.mark.multiprocess
def test_a_subsystem_run_alone_says_which_link_it_lacks(tmp_path):
    done = subprocess.run([*PBO, "run", str(REPO / "configs" / "follower.yaml"), "--no-live", "--duration", "1"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert "opens link 'arm_state', but the application provides no such link" in done.stderr
    assert "pbo run APP.yaml" in done.stderr


GOAL_B = np.array([-0.2, -0.3, 0.3, -0.2, 0.2, 0.4])  # the operator's second and last goal (configs/leader_follower.yaml)
SETTLED = 0.005  # rad: both arms this close to where they go before the run is stopped


def run_until_both_arms_settle(tmp_path, application: str) -> tuple[int, str, str]:
    """`pbo run APP` on the real clock until the operator is done, the leader holds the operator's last goal
    and the follower the leader's pose, then Ctrl-C: (exit status, stdout, stderr).

    Each subsystem starts on its own and would count a duration from its own start, so a fixed duration
    may end one before the others have done their part on a loaded machine; this waits for the arms instead.
    """
    said, complained = tmp_path / "stdout.txt", tmp_path / "stderr.txt"
    with said.open("w") as stdout, complained.open("w") as stderr:
        runner = subprocess.Popen([*PBO, "run", application, "--duration", "0", "--out", str(tmp_path / "out")],
                                  cwd=tmp_path, stdout=stdout, stderr=stderr, text=True)
    try:
        deadline = time.monotonic() + 180
        # the operator ends by itself once its application is done; its summary is awaited, so Ctrl-C cannot cut it off
        while "[operator] run summary" not in said.read_text() or not _both_arms_settled(runner.pid):
            assert runner.poll() is None, said.read_text() + complained.read_text()
            assert time.monotonic() < deadline, "the arms did not settle: " + said.read_text()
            time.sleep(0.2)
        runner.send_signal(signal.SIGINT)
        runner.wait(timeout=120)
    finally:
        if runner.poll() is None:
            runner.kill()
            runner.wait()
    return runner.returncode, said.read_text(), complained.read_text()


def _both_arms_settled(runner: int) -> bool:
    from pbo_runtime import PboError
    from pbo_runtime.ipc.control import live_runs
    from pbo_runtime.table.svar import attach

    ours = children_of(runner)  # each subsystem's supervisor, whose pid starts its run id
    tables = {sub: name for sub, run_id, name in live_runs() if int(run_id.split("-")[0]) in ours}
    if not {"leader", "follower"} <= set(tables):
        return False
    try:
        with attach(tables["leader"]) as leader, attach(tables["follower"]) as follower:
            goal, leader_at, follower_at = leader.read("q_d")[0], leader.read("q_m")[0], follower.read("q_m")[0]
    except PboError:  # a table still being filled in, or one whose run just ended
        return False
    return (np.allclose(goal, GOAL_B) and np.max(np.abs(leader_at - GOAL_B)) < SETTLED
            and np.max(np.abs(follower_at - leader_at)) < SETTLED)


def assert_application_ended_well(status: int, out, said: str) -> None:
    """The runner's status is the worst of its subsystems': 0, or 2 for timing faults only (support.assert_ended_well)."""
    reports = [json.loads((out / key / "report.json").read_text()) for key in ("leader", "follower", "operator")]
    for report in reports:
        assert_ended_well(2 if report["faults"] else 0, report, said)
    assert status == (2 if any(report["faults"] for report in reports) else 0), said


def assert_the_goal_reached_both_arms(out) -> None:
    leader = read_log(out / "leader" / "leader.mcap")
    follower = read_log(out / "follower" / "follower.mcap")
    operator = read_log(out / "operator" / "operator.mcap")
    sent, put_off = operator["message_counts"][-1]
    # two goals, and the initial value too if the console's first cycle came before the first job's write
    assert sent in (2.0, 3.0) and put_off == 0.0
    assert np.allclose(leader["q_d"][-1], GOAL_B)  # the leader's server took the last message
    assert np.max(np.abs(leader["q_m"][-1] - GOAL_B)) < 0.01  # and the leader got there
    assert np.max(np.abs(follower["q_d"][-1] - leader["q_m"][-1])) < 0.01  # the periodic link carried it
    assert np.max(np.abs(follower["q_m"][-1] - leader["q_m"][-1])) < 0.01  # and the follower got there too
    counts = follower["link_counts"]  # lost, reused, age, as logged every 10 ms
    # Lost and reused are the receiver's running totals of the link's items: they never go back.
    # No bound on either: the leader may stop before the follower's last cycles, which reuse its last item.
    assert (np.diff(counts[:, :2], axis=0) >= 0).all(), counts[:, :2]
    report = json.loads((out / "leader" / "report.json").read_text())
    goal = report["tasks"]["goal"]
    assert goal["cycles"] == sent and goal["dropped_events"] == 0, goal  # one release per message
    for key in ("leader", "follower", "operator"):
        assert_nothing_left(json.loads((out / key / "report.json").read_text()))


@pytest.mark.multiprocess
def test_the_operator_goal_message_moves_the_leader_and_the_follower_tracks_it_over_shared_memory(tmp_path):
    # The real clock, where each subsystem starts on its own: the arms are awaited, not a duration
    # (tests/test_application_replay.py runs the application on the simulated clock).
    status, out, err = run_until_both_arms_settle(tmp_path, str(APP))
    assert_application_ended_well(status, tmp_path / "out", out + err)
    assert "[leader] pbo: configuration 'lead' is on" in out and "[follower] run summary" in out
    assert "[operator] run summary: operator · operate" in out
    assert_the_goal_reached_both_arms(tmp_path / "out")
    assert [n for n in os.listdir("/dev/shm") if "pbo.leader_follower." in n] == []
    assert_the_links_are_gone(json.loads((tmp_path / "out" / "leader" / "report.json").read_text()))


def assert_the_links_are_gone(report: dict) -> None:
    """The runner removed every shm link: opened by name, since /dev/mqueue may not be mounted."""
    links = [spec for spec in report["links"].values() if spec["transport"] == "shm"]
    assert {spec.get("kind", "periodic") for spec in links} == {"periodic", "message"}
    for spec in links:
        with pytest.raises(posix_ipc.ExistentialError):
            if spec.get("kind") == "message":
                posix_ipc.MessageQueue(spec["object"])
            else:
                posix_ipc.SharedMemory(spec["object"])


@pytest.mark.multiprocess
def test_the_same_application_runs_over_zenoh_changed_only_in_yaml(tmp_path):
    path = write_app(tmp_path, links=SHIPPED_LINKS.replace("transport: shm", "transport: zenoh"))
    status, out, err = run_until_both_arms_settle(tmp_path, path)
    assert_application_ended_well(status, tmp_path / "out", out + err)
    assert "link 'arm_state': leader.send -> follower.receive (float64 [6], periodic, zenoh)" in out
    assert "link 'goal': operator.console -> leader.goal (float64 [6], messages, 4 queued at most, zenoh)" in out
    assert_the_goal_reached_both_arms(tmp_path / "out")


def test_a_zenoh_link_may_name_the_endpoint_its_listening_end_binds_for_another_machine(tmp_path):
    links = SHIPPED_LINKS.replace("transport: shm}", 'transport: zenoh, endpoint: "tcp/192.168.1.20:7447"}', 1)
    result = check_application(write_app(tmp_path, links=links))
    assert result.ok and result.application.links["arm_state"].endpoint == "tcp/192.168.1.20:7447"


@pytest.mark.parametrize("endpoint, wanted", [
    ('transport: shm, endpoint: "tcp/10.0.0.2:7447"', "takes no endpoint"),
    ('transport: zenoh, endpoint: "udp/10.0.0.2:7447"', "endpoint must be tcp/<host>:<port>"),
    ('transport: zenoh, endpoint: "tcp/10.0.0.2:99999"', "endpoint must be tcp/<host>:<port>"),
])
def test_a_bad_link_endpoint_is_refused_with_an_example(tmp_path, endpoint, wanted):
    result = check_application(write_app(tmp_path, links=SHIPPED_LINKS.replace("transport: shm}", endpoint + "}", 1)))
    assert codes(result) == ["E803"] and wanted in result.errors[0].message


def test_the_runner_hands_the_scheduler_choice_to_every_subsystem_and_otherwise_leaves_their_default():
    from pbo_runtime.supervisor.application_runner import ApplicationRunner

    application = check_application(APP).application
    default = ApplicationRunner(application, 1.0, lambda text: None)
    sched_other = ApplicationRunner(application, 1.0, lambda text: None, fifo=False)
    for key in application.subsystems:
        assert not {"--fifo", "--no-fifo"} & set(default.command(key))
        assert sched_other.command(key)[-1] == "--no-fifo"
    assert ApplicationRunner(application, 1.0, lambda text: None, fifo=True).command("leader")[-1] == "--fifo"


class SlowTerminal:
    """A terminal that takes 2 ms a line: the relay is still printing when the subsystem has ended."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def write(self, text: str) -> None:
        time.sleep(0.002)
        self.lines.append(text)

    def flush(self) -> None:
        pass


@pytest.mark.multiprocess
def test_the_runner_prints_an_ended_subsystems_last_lines_before_it_returns(monkeypatch):
    import sys

    from pbo_runtime.supervisor.application_runner import ApplicationRunner

    terminal = SlowTerminal()
    monkeypatch.setattr(sys, "stdout", terminal)
    runner = ApplicationRunner(check_application(APP).application, duration=None, say=lambda text: None)
    child = subprocess.Popen([sys.executable, "-c", "for i in range(200): print(i)\nprint('its summary, last')"],
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    runner.watch("operator", child)
    child.wait()  # it ended at once; printing its 201 lines takes the relay 0.4 s
    runner._stop_all()
    assert len(terminal.lines) == 201 and terminal.lines[-1] == "[operator] its summary, last\n"
