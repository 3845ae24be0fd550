"""The trackball of Cartesian teleoperation (TR Figure 10): scripted in the module, and as a device.

The device (driver trackball, TR §4.6.2) is played by a script or by the operator: its operator
input is written by the verb `pbo play`, here through the API's route (POST /api/verbs/play,
token and all) on a fake host, read by the driver in the same process; the module reads the
device through a real Task. End to end: configs/cartesian_teleop_hmi.yaml on the simulated
clock, played from the command line while it runs.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import signal
import subprocess
import uuid
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from drivers.trackball.driver import Trackball
from modules.trackball_input import TrackballInput
from pbo_runtime import ParamError, PboError
from pbo_runtime.api.app import create_app
from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.config.model import DeviceSpec, TaskSpec
from pbo_runtime.ipc import operator_input
from pbo_runtime.ipc.control import answer
from pbo_runtime.ipc.shm import object_name
from pbo_runtime.reports.lexicon import drivers
from pbo_runtime.reports.monitor import monitor_layout
from pbo_runtime.supervisor.commands import dispatch
from pbo_runtime.task.lifecycle import Task
from tests.fake_job_host import FakeJobHost
from tests.support import PBO, REPO, assert_nothing_left, start_run, task_spec, until, variables

HMI_CONFIG = REPO / "configs" / "cartesian_teleop_hmi.yaml"
TOKEN = "the-trackball-test-token"

POSE = np.array([0.5, -0.1, 0.2, 0.0, -0.4, 0.0])


def run(make_table, params, times):
    table = make_table(variables(("x_m", "float64", (6,)), ("x_d", "float64", (6,))))
    table.write("x_m", POSE, when=0)
    task = Task(task_spec(TrackballInput, params=params), TrackballInput, table)
    assert task.spawn(0.0), task.last_error
    task.turn_on(10.0)
    out = []
    for t in times:
        task.run_cycle(10.0 + t)
        out.append(table.read("x_d")[0] - POSE)
    return np.array(out)


def test_the_desired_pose_follows_the_waypoints_from_where_the_arm_was(make_table):
    offsets = run(make_table, {"script": [[1.0, 0.1, 0, 0, 0, 0, 0], [3.0, 0.1, 0, 0.2, 0, 0, 0]]}, [0.5, 1.0, 2.0, 3.0, 9.0])
    assert offsets[:, 0] == pytest.approx([0.05, 0.1, 0.1, 0.1, 0.1])
    assert offsets[:, 2] == pytest.approx([0.0, 0.0, 0.1, 0.2, 0.2])  # held after the last waypoint


def test_waypoints_can_come_from_a_csv_file_with_a_header(make_table, tmp_path):
    path = tmp_path / "session.csv"
    path.write_text("t,dx,dy,dz,rx,ry,rz\n1.0,0,0.1,0,0,0,0\n")
    offsets = run(make_table, {"file": str(path)}, [0.5, 2.0])
    assert offsets[:, 1] == pytest.approx([0.05, 0.1])


@pytest.mark.parametrize(("params", "message"), [
    ({}, r"give exactly one of device \(a trackball device\), script"),
    ({"script": [[1.0, 0, 0]]}, r"each waypoint is 7 numbers"),
    ({"script": [[2.0, 0, 0, 0, 0, 0, 0], [1.0, 0, 0, 0, 0, 0, 0]]}, r"waypoint times must start at >= 0 and increase"),
])
def test_bad_scripts_are_refused(params, message):
    with pytest.raises(ParamError, match=message):
        TrackballInput.build_params(params)


# --- the trackball device ----------------------------------------------------------------------------


def _run_id() -> str:
    """A run id of this test process: conftest fails a test that leaves an object named with it."""
    return f"{os.getpid()}-{uuid.uuid4().hex[:6]}"


def _ball(options: dict, subsystem: str = "balltest", run_id: str | None = None, device: str = "ball") -> Trackball:
    return Trackball(object_name(subsystem, run_id or _run_id(), "plant"), options, device=device)


def test_pbo_lexicon_lists_the_trackball_driver_as_a_sensor_actuator_driver():
    entries = {e["name"]: e for e in drivers()}
    assert entries["trackball"]["kind"] == "sensor-actuator (TR 4.6.2)"
    assert entries["trackball"]["class"] == "drivers.trackball.driver:Trackball"


@pytest.mark.parametrize(("options", "message"), [
    ({}, r"source: script takes exactly one of script \(inline waypoints\) or file"),
    ({"source": "hmi", "script": [[1, 0, 0, 0, 0, 0, 0]]}, r"source: hmi is played by the operator; it takes no script"),
    ({"source": "joystick"}, r"source must be one of script, hmi, got: 'joystick'"),
    ({"source": "hmi", "reach": 0}, r"option reach must be a number in \(0, 10\] \(m\), got: 0"),
    ({"source": "hmi", "turn": float("inf")}, r"option turn must be a number in \(0, 10\] \(rad\), got: inf"),
    ({"script": [[1.0, 0, 0]]}, r"each waypoint is 7 numbers"),
    ({"source": "hmi", "speed": 1}, r"unknown trackball option\(s\) \['speed'\]"),
])
def test_bad_trackball_options_are_refused_as_the_checker_reports_them(options, message):
    with pytest.raises(ValueError, match=message):
        Trackball.check_options(options)


def test_a_scripted_ball_plays_its_waypoints_within_its_travel():
    ball = _ball({"script": [[1.0, 0.1, 0, 0, 0, 0, 0], [3.0, 0.5, 0, 0.2, 0, 0, 0]], "reach": 0.3})
    out = np.zeros(6)
    seen = []
    for t in (0.5, 1.0, 2.0, 9.0):
        assert ball.read_offset(t, out)
        seen.append(out.copy())
    assert [s[0] for s in seen] == pytest.approx([0.05, 0.1, 0.3, 0.3])  # 0.5 at 3 s is held at the 0.3 m reach
    assert [s[2] for s in seen] == pytest.approx([0.0, 0.0, 0.1, 0.2])
    ball.close()


def test_an_operators_ball_reads_zeros_until_played_then_what_was_played_within_its_travel():
    run_id = _run_id()
    ball = _ball({"source": "hmi", "reach": 0.1, "turn": 0.5}, run_id=run_id)
    out = np.ones(6)
    try:
        assert not ball.read_offset(0.0, out) and not out.any()
        assert operator_input.play("balltest", run_id, "ball", [0.05, 0, -0.2, 0, 0, 0.7]) == 1
        assert ball.read_offset(0.0, out)
        assert out.tolist() == pytest.approx([0.05, 0, -0.1, 0, 0, 0.5])
        with pytest.raises(PboError, match=r"device 'ball' takes 6 finite numbers, got: \[0.1, nan"):
            operator_input.play("balltest", run_id, "ball", [0.1, float("nan"), 0, 0, 0, 0])
        ball.read_offset(0.0, out)
        assert out[0] == pytest.approx(0.05)  # the refused values never reached it
    finally:
        ball.close()
    with pytest.raises(PboError, match=r"device 'ball' takes no operator input in this run"):
        operator_input.play("balltest", run_id, "ball", [0.0] * 6)


def test_reading_the_operators_ball_allocates_nothing():
    from tests.support import allocation_peak, one_array

    ball = _ball({"source": "hmi"})
    out = np.zeros(6)
    try:
        assert allocation_peak(lambda: ball.read_offset(0.0, out)) < one_array()
    finally:
        ball.close()


class _HostLink:
    """The API's link to a run, served by `commands.dispatch` on a fake host (as the supervisor answers)."""

    def __init__(self, host: FakeJobHost) -> None:
        self.host = host

    def request(self, command: str, arguments: dict[str, Any], timeout: float) -> dict[str, Any]:
        return answer(lambda c, a: dispatch(self.host, c, a), command, arguments)

    def runs(self) -> list[dict[str, Any]]:
        return [{"subsystem": self.host.subsystem.name, "run_id": self.host.run_id}]


def test_the_operator_plays_the_ball_through_the_apis_play_route_and_the_monitor_offers_its_controls():
    subsystem = load_subsystem(HMI_CONFIG)
    host = FakeJobHost(subsystem, "teleop")
    host.run_id = _run_id()
    ball = _ball(dict(subsystem.devices["ball"].options), subsystem.name, host.run_id)
    client = TestClient(create_app(_HostLink(host), TOKEN, str(HMI_CONFIG)))
    bearer = {"Authorization": f"Bearer {TOKEN}"}
    out = np.zeros(6)
    try:
        assert client.post("/api/verbs/play", json={"device": "ball", "values": [0.05, 0, 0.03, 0, 0, 0]}).status_code == 401
        reply = client.post("/api/verbs/play", json={"device": "ball", "values": [0.05, 0, 0.03, 0, 0, 0]}, headers=bearer)
        assert reply.status_code == 200 and reply.json()["writes"] == 1, reply.text
        assert ball.read_offset(0.0, out) and out.tolist() == pytest.approx([0.05, 0, 0.03, 0, 0, 0])
        refused = client.post("/api/verbs/play", json={"device": "arm", "values": [0.0] * 6}, headers=bearer)
        assert refused.status_code >= 400 and "device 'arm' takes no operator input" in refused.json()["error"]
        unknown = client.post("/api/verbs/play", json={"device": "joystick", "values": [0.0] * 6}, headers=bearer)
        assert unknown.status_code == 400 and unknown.json()["error"].startswith("no device 'joystick' (devices: arm, ball)")
    finally:
        ball.close()
    controls = monitor_layout(subsystem)["played"]["ball"]
    assert [(c["name"], c["unit"], c["max"]) for c in controls] == [
        ("dx", "m", 0.1), ("dy", "m", 0.1), ("dz", "m", 0.1), ("rx", "rad", 0.5), ("ry", "rad", 0.5), ("rz", "rad", 0.5)]


def test_the_module_reads_the_ball_through_its_device_from_where_the_arm_was(make_table):
    run_id = _run_id()
    table = make_table(variables(("x_m", "float64", (6,)), ("x_d", "float64", (6,))))
    table.write("x_m", POSE, when=0)
    device = DeviceSpec("ball", "trackball", True, {"source": "hmi"})

    def opener(spec: DeviceSpec, _task: TaskSpec) -> Trackball:
        return Trackball(object_name("balltest", run_id, "plant"), spec.options, device=spec.name)

    spec = dataclasses.replace(task_spec(TrackballInput, params={"device": "ball"}), resources=("ball",))
    task = Task(spec, TrackballInput, table, {}, devices={"ball": device}, opener=opener)
    assert task.spawn(0.0), task.last_error
    task.turn_on(10.0)
    task.run_cycle(10.1)
    assert table.read("x_d")[0] == pytest.approx(POSE)  # not played yet: the arm stays where it was
    operator_input.play("balltest", run_id, "ball", [0.05, 0, 0.02, 0, 0, 0.1])
    task.run_cycle(10.2)
    assert table.read("x_d")[0] - POSE == pytest.approx([0.05, 0, 0.02, 0, 0, 0.1])
    task.kill()
    with pytest.raises(PboError, match="takes no operator input"):  # closed with its task: unlinked
        operator_input.play("balltest", run_id, "ball", [0.0] * 6)


def _svar(subsystem: str, name: str) -> np.ndarray:
    shown = subprocess.run([*PBO, "svar", name, "--subsystem", subsystem, "--format", "json"],
                           capture_output=True, text=True, timeout=60)
    assert shown.returncode == 0, shown.stderr
    row = next(r for r in json.loads(shown.stdout)["variables"] if r["name"] == name)
    return np.array([float(x) for x in re.findall(r"[-+]?\d+(?:\.\d*)?(?:e[-+]?\d+)?", row["value"])])  # its text, as shown


@pytest.mark.multiprocess
def test_cartesian_teleoperation_follows_the_ball_the_operator_plays_while_it_runs(tmp_path):
    subsystem = "ball_played"
    path = tmp_path / f"{subsystem}.yaml"
    path.write_text(HMI_CONFIG.read_text().replace("subsystem: teleop_hmi", f"subsystem: {subsystem}"))
    run = start_run(path, tmp_path, "--clock", "sim", "--duration", "600", "--out", str(tmp_path / "out"))
    try:
        start = _svar(subsystem, "x_d")
        played = subprocess.run([*PBO, "play", "ball", "0.05", "0", "0.03", "0", "0", "0", "--subsystem", subsystem],
                                capture_output=True, text=True, timeout=60)
        assert played.returncode == 0, played.stderr
        assert "device 'ball' plays [0.05, 0, 0.03, 0, 0, 0]" in played.stdout
        until(lambda: np.allclose(_svar(subsystem, "x_d") - start, [0.05, 0, 0.03, 0, 0, 0], atol=2e-3),
              "x_d moved by what was played", safety_net=150)
        until(lambda: np.linalg.norm(_svar(subsystem, "x_m")[:3] - start[:3] - [0.05, 0, 0.03]) < 0.01,
              "the hand followed", safety_net=150)
    finally:
        run.send_signal(signal.SIGINT)
        _out, err = run.communicate(timeout=120)
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["tasks"]["trackball"]["state"] == "ON" and run.returncode == 0, err
    assert_nothing_left(report)
    assert [n for n in os.listdir("/dev/shm") if f"pbo.{subsystem}." in n] == []
