"""The ROS 2 bridge on real DDS: what a ROS 2 node on the same domain sees of a subsystem, and sends it.

The other side is always a separate Cyclone DDS participant in a process of its own
(tests/ros2_peer.py), its message types declared as ROS 2's generated IDL declares them. Each test
takes a DDS domain of its own, so runs side by side never see each other's topics.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("cyclonedds")

from modules._joint_states_publisher import record_size
from modules.ros2_goal import Ros2Goal
from modules.ros2_joint_states import Ros2JointStates
from pbo_runtime import DdsProcess, ModuleError, Status
from pbo_runtime.errors import EXTRAS, ParamError
from pbo_runtime.ipc.shm import children_of
from pbo_runtime.links import ros2_messages as ros2
from pbo_runtime.task.lifecycle import Task
from tests.support import (
    PBO,
    REPO,
    allocation_peak,
    assert_ended_well,
    config_copy,
    one_array,
    own_dds_domain,
    process_gone,
    read_until,
    run_output,
    run_processes,
    start_run,
    task_spec,
    until,
    variables,
)
from tests.support import ros2_peer as peer
from tests.support import ros2_peer_said as peer_said

# --- the wire: names, types, CDR ----------------------------------------------------------------


@pytest.mark.parametrize("kind, typename", [
    (ros2.JointState, "sensor_msgs::msg::dds_::JointState_"),
    (ros2.Float64MultiArray, "std_msgs::msg::dds_::Float64MultiArray_"),
    (ros2.JointTrajectory, "trajectory_msgs::msg::dds_::JointTrajectory_"),
    (ros2.Header, "std_msgs::msg::dds_::Header_"),
    (ros2.Time, "builtin_interfaces::msg::dds_::Time_"),
])
def test_a_message_type_has_the_dds_name_ros2_gives_it(kind, typename):
    assert kind.__idl_typename__ == typename


def test_a_float64_multi_array_is_serialized_as_rmw_cyclonedds_writes_it():
    # CDR little endian (encapsulation 0x0001); an empty dim sequence, data_offset, then the data's
    # length and its doubles aligned to 8 from the start of the payload.
    wire = ros2.Float64MultiArray(data=[1.0, 2.0]).serialize()
    assert wire == bytes.fromhex("00010000" "00000000" "00000000" "02000000" "00000000"
                                 "000000000000f03f" "0000000000000040")


def test_a_joint_state_is_serialized_with_cdrs_string_and_sequence_alignment():
    # Offsets from the payload's start: the stamp, frame_id (its length counts the NUL), padding to
    # 4, the name sequence of one string, padding to 4, position (its double at 32, aligned to 8),
    # then the empty velocity and effort sequences.
    message = ros2.JointState(header=ros2.Header(stamp=ros2.Time(sec=1, nanosec=2), frame_id="f"), name=["a"], position=[1.0])
    assert message.serialize() == bytes.fromhex(
        "00010000" "01000000" "02000000" "02000000" "6600" "0000" "01000000" "02000000" "6100" "0000"
        "01000000" "000000000000f03f" "00000000" "00000000")


@pytest.mark.parametrize("name, dds", [("/joint_states", "rt/joint_states"), ("pbo/q_d", "rt/pbo/q_d"),
                                       ("/forward_effort_controller/commands", "rt/forward_effort_controller/commands")])
def test_a_ros2_topic_is_the_dds_topic_under_rt(name, dds):
    assert ros2.dds_topic(ros2.check_topic(name)) == dds


@pytest.mark.parametrize("name", ["", "/", "joint states", "/2joints", "/a//b", "/a/"])
def test_a_topic_that_is_not_a_ros2_name_is_refused(name):
    with pytest.raises(ValueError, match="topic must be a ROS 2 name"):
        ros2.check_topic(name)


@pytest.mark.parametrize("configured, environment, domain", [(-1, None, 0), (-1, "42", 42), (7, "42", 7), (-1, "x", 0)])
def test_the_domain_is_the_configured_one_else_ros_domain_id_else_zero(monkeypatch, configured, environment, domain):
    if environment is None:
        monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    else:
        monkeypatch.setenv("ROS_DOMAIN_ID", environment)
    assert ros2.domain_id(configured) == domain


def test_the_default_qos_is_ros2s_reliable_volatile_keep_last_10():
    text = str(ros2.ros2_qos())
    assert "Reliability.Reliable" in text and "Durability.Volatile" in text and "KeepLast(depth=10)" in text


def test_a_missing_cyclonedds_names_the_ros2_extra():
    assert EXTRAS["cyclonedds"] == "ros2"


@pytest.mark.parametrize("module, params, wanted", [
    (Ros2Goal, {"type": "std_msgs/msg/String"}, "type must be one of"),
    (Ros2Goal, {"fresh_within": -1}, r"fresh_within must be in \[0, 3600\]"),
    (Ros2Goal, {"domain": 233}, r"domain must be in \[-1, 232\]"),
    (Ros2JointStates, {"joint_names": ["a", "a"]}, "joint_names must be distinct"),
    (Ros2JointStates, {"topic": ""}, "topic must be a ROS 2 topic name"),
])
def test_a_bridge_parameter_out_of_its_rules_is_refused(module, params, wanted):
    with pytest.raises(ParamError, match=wanted):
        module.build_params(params)


# --- the modules on a real table, their DDS peer in another process ----------------------------


def _goal_task(table, domain: int, **params) -> Task:
    spec = task_spec(Ros2Goal, name="goal", ports={"value": "q_d"}, params={"domain": domain, **params}, period=0.01)
    return Task(spec, Ros2Goal, table)


def test_a_joint_states_task_whose_names_do_not_fit_q_m_fails_its_spawn(make_table):
    table = make_table(variables(("q_m", "float64", (3,)), ("qd_m", "float64", (3,)), ("tau", "float64", (3,))))
    spec = task_spec(Ros2JointStates, name="states", dims={"NDOF": 3},
                     params={"joint_names": ["a", "b"], "domain": own_dds_domain()})
    task = Task(spec, Ros2JointStates, table, {"NDOF": 3})
    assert not task.spawn(0.0)
    assert "joint_names must name the 3 joints of q_m, got 2" in task.last_error


@pytest.mark.multiprocess
def test_a_joint_states_publisher_that_cannot_start_says_why():
    setup = {"domain": 300, "topic": "/joint_states", "names": ["a"], "frame_id": "", "node": "pbo_states"}  # past DDS's ports
    with pytest.raises(ModuleError, match=r"states: its JointState publisher process did not start: DDSException: .*Participant"):
        DdsProcess("modules._joint_states_publisher", setup, [record_size(1)], "states: its JointState publisher", "")


@pytest.mark.multiprocess
def test_a_dds_process_ends_when_its_rtpu_dies_and_shares_nothing_through_dev_shm():
    setup = {"domain": own_dds_domain(), "topic": "/joint_states", "names": ["a"], "frame_id": "", "node": "pbo_states"}
    holder = subprocess.Popen(  # an RTPU's part: it holds the publisher process, then dies at once (SIGKILL)
        [sys.executable, "-c", "import json, sys, time; from pbo_runtime import DdsProcess; "
         "process = DdsProcess('modules._joint_states_publisher', json.loads(sys.argv[1]), [4], 'states', ''); "
         "print(process.process.pid, flush=True); time.sleep(600)", json.dumps(setup)],
        cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        child = int(holder.stdout.readline())
        files = [os.readlink(f"/proc/{child}/fd/{fd}") for fd in os.listdir(f"/proc/{child}/fd")]
    finally:
        holder.kill()
        run_output(holder)
    until(lambda: process_gone(child), "the publisher process ends with its holder")
    assert "/memfd:pbo-dds (deleted)" in files  # what they share has no name: nothing to leave in /dev/shm
    assert [file for file in files if file.startswith("/dev/shm")] == []


@pytest.mark.multiprocess
@pytest.mark.parametrize("kind, sent, written, refused", [
    ("std_msgs/msg/Float64MultiArray", [0.1, 0.2, 0.3], [0.1, 0.2, 0.3], False),
    # a trajectory's last point, its joints named out of order: written in the output's order
    ("trajectory_msgs/msg/JointTrajectory", [3, 1, 2, 0.3, 0.1, 0.2], [0.1, 0.2, 0.3], False),
    ("std_msgs/msg/Float64MultiArray", [0.1, 0.2], [9.0, 9.0, 9.0], True),  # another size: never written
], ids=["array", "trajectory", "wrong size"])
def test_a_goal_published_by_another_node_is_written_and_a_silent_topic_makes_it_stale(make_table, capfd, kind, sent, written,
                                                                                       refused):
    table = make_table(variables(("q_d", "float64", (3,))))
    table.write("q_d", np.array([9.0, 9.0, 9.0]), when=0.0)
    domain = own_dds_domain()
    task = _goal_task(table, domain, type=kind, fresh_within=0.5)
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0), task.last_error
    try:
        assert task.run_cycle(0.0) is Status.STABLE  # nothing came yet: the critical tasks hold
        publisher = peer("publish", domain, "/pbo/q_d", kind, 1.0, *sent)
        clock = [0.0]

        def arrived() -> bool:
            clock[0] += 0.01
            task.run_cycle(clock[0])
            return task.module.refused > 0 if refused else bool(np.array_equal(table.read("q_d")[0], written))

        until(arrived, "the peer's message reaches the task")
        assert peer_said(publisher)["written"] > 0
        np.testing.assert_array_equal(table.read("q_d")[0], written)
        last = clock[0] + 0.01
        status = task.run_cycle(last)
        assert status is (Status.STABLE if refused else Status.CONTINUE)
        assert task.run_cycle(last + 0.6) is Status.STABLE  # the peer is gone: past its bound, stale
        np.testing.assert_array_equal(table.read("q_d")[0], written)  # the last goal stays written
    finally:
        task.kill()
    said = capfd.readouterr().err  # (the subscriber process's stderr is the RTPU's)
    if refused:
        assert f"task 'goal' refused a {kind} on /pbo/q_d (2 values, the output takes 3); 1 refused so far" in said, said
    else:
        assert "refused" not in said, said


@pytest.mark.multiprocess
def test_a_goal_whose_subscriber_process_dies_is_stale_from_then_on_and_the_run_says_so(make_table, capfd):
    table = make_table(variables(("q_d", "float64", (3,))))
    task = _goal_task(table, own_dds_domain())  # fresh_within 0: a silent topic alone is never stale
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0), task.last_error
    try:
        assert task.run_cycle(0.0) is Status.CONTINUE
        subscriber = task.module._subscriber
        subscriber.process.kill()
        until(lambda: subscriber.ended, "the task learns that its subscriber process ended")
        assert task.run_cycle(0.01) is Status.STABLE
    finally:
        task.kill()
    assert (f"task 'goal': its ROS 2 subscriber process (pid {subscriber.process.pid}) ended with exit status -9: "
            "/pbo/q_d is a stale input from now on") in capfd.readouterr().err


@pytest.mark.multiprocess
@pytest.mark.parametrize("module, readers, writers", [
    (Ros2JointStates, [], ["rt/joint_states"]),  # announced by its publisher process
    (Ros2Goal, ["rt/pbo/q_d"], []),
], ids=["joint states", "goal"])
def test_a_bridge_task_is_a_ros2_node_that_another_node_sees_on_ros_discovery_info(make_table, module, readers, writers):
    table = make_table(variables(("q_d", "float64", (3,)), ("q_m", "float64", (3,)), ("qd_m", "float64", (3,)),
                                 ("tau", "float64", (3,))))
    domain = own_dds_domain()
    task = Task(task_spec(module, name="bridge", dims={"NDOF": 3}, ports={"value": "q_d"}, params={"domain": domain}), module,
                table, {"NDOF": 3})
    assert task.spawn(0.0), task.last_error
    try:
        seen = peer_said(peer("discovery", domain, "pbo_bridge"))  # joins after the node said it: transient local
    finally:
        task.kill()
    assert seen == {"found": True, "namespace": "/", "participant_gid_bytes": 16, "readers": readers, "writers": writers}


@pytest.mark.parametrize("text, name", [("pbo_goal", "pbo_goal"), ("pbo_arm-1.x", "pbo_arm_1_x"), ("2arm", "pbo_2arm")])
def test_a_node_name_is_made_of_letters_digits_and_underscores(text, name):
    assert ros2.node_name(text) == name


def test_ros_discovery_info_is_serialized_as_rmw_dds_common_declares_it():
    # The participant's 16-byte gid, one node: namespace, name, an empty reader sequence, one writer gid.
    node = ros2.NodeEntitiesInfo(node_namespace="/", node_name="n", writer_gid_seq=[ros2.Gid(data=[7] * 16)])
    wire = ros2.ParticipantEntitiesInfo(gid=ros2.Gid(data=list(range(16))), node_entities_info_seq=[node]).serialize()
    assert wire == bytes.fromhex("00010000" + bytes(range(16)).hex() + "01000000" "02000000" "2f000000" "02000000" "6e000000"
                                 "00000000" "01000000" + "07" * 16)


# --- the shipped bridge on the real clock -------------------------------------------------------


@pytest.mark.multiprocess
def test_ros2_bridge_publishes_joint_states_at_100_hz_and_takes_its_goal_from_a_ros2_node(tmp_path, monkeypatch):
    domain = own_dds_domain()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))  # the run's RTPUs inherit it
    config = config_copy(REPO / "configs" / "ros2_bridge.yaml", tmp_path, f"ros2_{os.getpid()}")
    report_path = tmp_path / "report.json"
    run = start_run(config, tmp_path, "--duration", "120", "--report", str(report_path))
    try:
        heard = peer_said(peer("listen", domain, 3.0))
        assert 90 <= heard["rate"] <= 110, heard  # 10 ms period, counted over 3 s
        assert heard["names"] == [f"joint{i}" for i in range(1, 7)]
        assert np.abs(np.subtract(heard["position"], [0.3, -0.5, 0.5, 0.2, 0.4, 0.2])).max() < 0.05  # at its initial goal
        assert heard["stamp_sec"] > 1_700_000_000  # Unix time
        goal = [0.0, -0.3, 0.3, 0.0, 0.2, 0.0]
        reached = peer_said(peer("goal", domain, 90.0, *goal))
        assert reached["reached"], reached
        assert np.abs(np.subtract(reached["position"], goal)).max() < 0.01
    finally:
        if run.poll() is None:
            run.send_signal(signal.SIGINT)
        _out, err = run_output(run)
    assert "Traceback" not in err, err
    assert_ended_well(run.returncode, json.loads(report_path.read_text()), err)


@pytest.mark.multiprocess
def test_a_silent_goal_topic_past_its_bound_makes_the_robot_hold_and_the_run_say_so(tmp_path, monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", str(own_dds_domain()))  # no node publishes there
    config = config_copy(REPO / "configs" / "ros2_bridge.yaml", tmp_path, f"ros2_silent_{os.getpid()}",
                         replace=(("type: std_msgs/msg/Float64MultiArray}",
                                   "type: std_msgs/msg/Float64MultiArray, fresh_within: 0.5}"),))
    report_path = tmp_path / "report.json"
    done = subprocess.run([*PBO, "run", str(config), "--clock", "sim", "--duration", "1", "--no-live",
                           "--report", str(report_path)],
                          cwd=tmp_path, capture_output=True, text=True, timeout=180)
    assert done.returncode == 2, done.stderr
    assert ("critical task 'robot' runs its locally stable behaviour: a task upstream has no fresh input (its cycle "
            "returned STABLE: a link's item or a topic's message past its bound)") in done.stdout + done.stderr
    report = json.loads(report_path.read_text())
    assert report["faults"] == ["task 'goal' had no fresh input until the stop, from 0.000 s into the run (its cycle returned "
                                "STABLE: a link's item or a topic's message past its bound), "
                                "and the critical tasks held meanwhile"]
    robot = report["tasks"]["robot"]
    assert robot["stable_cycles"] == robot["cycles"] - 1  # held from its second cycle on (the first ran before goal's first)


@pytest.mark.multiprocess
def test_a_goal_subscriber_process_killed_in_a_run_makes_the_robot_hold_and_the_run_say_why(tmp_path, monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", str(own_dds_domain()))
    config = config_copy(REPO / "configs" / "ros2_bridge.yaml", tmp_path, f"ros2_killed_{os.getpid()}")  # fresh_within: 0
    report_path = tmp_path / "report.json"
    run = start_run(config, tmp_path, "--duration", "120", "--report", str(report_path))
    try:
        rtpu0 = run_processes(run)["rtpu0"]
        [subscriber] = [pid for pid, command in children_of(rtpu0).items() if "modules._ros2_goal_subscriber" in command]
        os.kill(subscriber, signal.SIGKILL)
        read_until(run, "critical task 'robot' runs its locally stable behaviour: a task upstream has no fresh input")
    finally:
        if run.poll() is None:
            run.send_signal(signal.SIGINT)
        _out, err = run_output(run)
    assert (f"task 'goal': its ROS 2 subscriber process (pid {subscriber}) ended with exit status -9: "
            "/pbo/q_d is a stale input from now on") in err, err
    assert "Traceback" not in err, err
    assert run.returncode == 2, err
    faults = json.loads(report_path.read_text())["faults"]
    assert any(fault.startswith("task 'goal' had no fresh input until the stop") for fault in faults), faults


@pytest.mark.parametrize("module", [Ros2Goal, Ros2JointStates])
def test_a_bridge_task_without_cyclonedds_fails_its_spawn_naming_the_ros2_extra(make_table, monkeypatch, module):
    monkeypatch.setitem(sys.modules, "cyclonedds", None)  # as if never installed: importing it raises ImportError
    table = make_table(variables(("q_d", "float64", (3,)), ("q_m", "float64", (3,)), ("qd_m", "float64", (3,)),
                                 ("tau", "float64", (3,))))
    spec = task_spec(module, name="bridge", dims={"NDOF": 3}, ports={"value": "q_d"}, params={"domain": own_dds_domain()})
    task = Task(spec, module, table, {"NDOF": 3})
    assert not task.spawn(0.0)
    name = module.__module__.split(".")[-1]  # ros2_goal, ros2_joint_states: the module's name in a YAML file
    assert (f"the {name} module needs the 'ros2' extra (cyclonedds is not installed): "
            "pip install 'pbo-runtime[ros2]'") in task.last_error


@pytest.mark.multiprocess
@pytest.mark.parametrize("module", [Ros2JointStates, Ros2Goal])
def test_a_bridge_tasks_cycle_allocates_nothing(make_table, module):
    table = make_table(variables(("q_d", "float64", (6,)), ("q_m", "float64", (6,)), ("qd_m", "float64", (6,)),
                                 ("tau", "float64", (6,))))
    dims = {"NDOF": 6}
    spec = task_spec(module, name="bridge", dims=dims, ports={"value": "q_d"}, params={"domain": own_dds_domain()})
    task = Task(spec, module, table, dims)
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0), task.last_error
    try:
        bridge = task.module

        def a_new_message_every_cycle() -> None:  # (as the subscriber process writes one: the record's number moves)
            bridge._record.begin()
            bridge._record.end()
            bridge.cycle()

        assert allocation_peak(bridge.cycle if module is Ros2JointStates else a_new_message_every_cycle) < one_array()
    finally:
        task.kill()
