"""`pbo ros2 jobs`: a ROS 2 message starts a job of a live run, its values the job's object.

The ROS 2 side is a separate Cyclone DDS participant in a process of its own (tests/ros2_peer.py),
its types declared as ROS 2 declares them; each test takes a DDS domain of its own.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess

import numpy as np
import pytest

pytest.importorskip("cyclonedds")

from pbo_runtime.cli.main import main
from tests.support import PBO, REPO, assert_ended_well, config_copy, own_dds_domain, read_until, run_output, start_run
from tests.support import ros2_peer as peer
from tests.support import ros2_peer_said as peer_said

GOAL_TASK = """  goal:   {module: ros2_goal, rtpu: rtpu0, period: 10 ms,
           params: {topic: /pbo/q_d, type: std_msgs/msg/Float64MultiArray}, ports: {value: q_d}}
"""
# The bridge's demo less its goal task: q_d is then the `reach` job's object, as an operator gives it.
WITH_A_JOB = ((GOAL_TASK, ""), ("bridge: [robot, goal, traj, pid, joint_states]",
                                 'bridge: [robot, traj, pid, joint_states]\njobs:\n'
                                 '  reach: {configuration: bridge, post: "max(abs(q_m - q_d)) < 0.01"}'))


def jobs_node(subsystem: str, *arguments: str) -> subprocess.Popen:
    return subprocess.Popen([*PBO, "ros2", "jobs", "reach", "--subsystem", subsystem, *arguments], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.multiprocess
def test_a_joint_trajectory_starts_the_reach_job_with_its_end_as_the_object_and_the_arm_gets_there(tmp_path, monkeypatch):
    domain = own_dds_domain()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))  # the run, the jobs node and the peers inherit it
    subsystem = f"ros2_jobs_{os.getpid()}"
    config = config_copy(REPO / "configs" / "ros2_bridge.yaml", tmp_path, subsystem, replace=WITH_A_JOB)
    report_path = tmp_path / "report.json"
    run = start_run(config, tmp_path, "--duration", "120", "--report", str(report_path))
    try:
        node = jobs_node(subsystem, "--once")
        assert "listening on /pbo/reach" in read_until(node, "listening on")
        goal = [0.0, -0.3, 0.3, 0.0, 0.2, 0.0]
        # the trajectory names its joints out of order: its last point is reordered into q_d's
        order = [3, 1, 2, 6, 5, 4]
        publisher = peer("publish", domain, "/pbo/reach", "trajectory_msgs/msg/JointTrajectory", 60.0, *order,
                         *[goal[i - 1] for i in order])
        out, err = run_output(node, timeout=120)
        publisher.kill()
        publisher.wait()
        assert node.returncode == 0, err
        assert f"job 'reach' started with {goal} (configuration 'bridge')" in out
        reached = peer_said(peer("watch", domain, 90.0, *goal))
        assert reached["reached"], reached
        assert np.abs(np.subtract(reached["position"], goal)).max() < 0.01
    finally:
        if run.poll() is None:
            run.send_signal(signal.SIGINT)
        out, err = run_output(run)
    report = json.loads(report_path.read_text())
    assert [m["label"] for m in report["marks"]].count("job reach starts") == 1  # --once: one message, one job
    np.testing.assert_allclose(report["variables"]["q_d"]["value"], goal)  # the job's object, reordered
    assert np.abs(np.subtract(report["variables"]["q_m"]["value"], goal)).max() < 0.01
    assert_ended_well(run.returncode, report, err)


@pytest.mark.multiprocess
def test_a_message_of_another_size_than_the_object_is_refused_and_the_node_listens_on(tmp_path, monkeypatch):
    domain = own_dds_domain()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    subsystem = f"ros2_jobs_refused_{os.getpid()}"
    config = config_copy(REPO / "configs" / "ros2_bridge.yaml", tmp_path, subsystem, replace=WITH_A_JOB)
    run = start_run(config, tmp_path, "--duration", "120")
    try:
        node = jobs_node(subsystem, "--type", "std_msgs/msg/Float64MultiArray")
        read_until(node, "listening on")
        publisher = peer("publish", domain, "/pbo/reach", "std_msgs/msg/Float64MultiArray", 1.0, 0.1, 0.2)
        assert peer_said(publisher)["written"] > 0
        node.send_signal(signal.SIGINT)
        out, err = run_output(node, timeout=60)
        assert "job 'reach' started" not in out
        assert "refused: 'ros2_jobs_refused_" in err and "takes 6 values" in err, err
    finally:
        run.send_signal(signal.SIGINT)
        run_output(run)


def test_a_topic_that_is_not_a_ros2_name_is_refused_with_exit_1(capsys):
    assert main(["ros2", "jobs", "reach", "--topic", "not a name"]) == 1
    assert "error: --topic: topic must be a ROS 2 name" in capsys.readouterr().err


def test_without_a_live_run_it_says_so_and_exits_2(capsys):
    assert main(["ros2", "jobs", "reach", "--subsystem", f"no_such_subsystem_{os.getpid()}"]) == 2
    assert "error: " in capsys.readouterr().err
