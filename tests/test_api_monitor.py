"""The monitor's logic and routes, in-process: the bus load measured from a live run's task rates
(analysis.bus.measured_live), the arm's joint frames by forward kinematics of the ARM and EE tables
(reports.arm, held to the DH product of the tests' own oracle), what the
monitor reads of a file (reports.monitor), and the routes over them (api.monitor) with FastAPI's
TestClient. The run behind the app is a unit test's link (`StatusLink`): a fixed status reply and a
real table made with StateTable.create; no process is started.
"""

from __future__ import annotations

import math
import os
import uuid
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from pbo_runtime import Arm
from pbo_runtime.analysis import bus
from pbo_runtime.api.app import create_app
from pbo_runtime.api.link import NoRun
from pbo_runtime.config import bus_model
from pbo_runtime.config.loader import check_file
from pbo_runtime.config.model import Subsystem
from pbo_runtime.ipc import messages
from pbo_runtime.objects import registry
from pbo_runtime.reports.arm import ArmFrames
from pbo_runtime.reports.monitor import monitor_layout
from pbo_runtime.table.svar import TableView, attach
from pbo_runtime.table.table import StateTable, TableLayout
from tests.support import DEMO, REPO, arm_tables, dh_forward_kinematics

TOKEN = "the-token-of-this-test"
BEARER = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture(scope="module")
def demo() -> Subsystem:
    result = check_file(str(DEMO))
    assert result.subsystem is not None and not result.errors
    return result.subsystem


def running(rates: dict[str, float], states: dict[str, str] | None = None, configuration: str = "joint_pid") -> dict[str, Any]:
    """A status reply of the demo (only what the monitor reads of it)."""
    rtpu = {"robot": "rtpu1"}
    return {"ok": True, "subsystem": "puma", "run_id": "1234-abcdef", "file": str(DEMO), "configuration": configuration,
            "tasks": [{"task": name, "rtpu": rtpu.get(name, "rtpu0"), "state": (states or {}).get(name, "ON"),
                       "rate": rate, "cycles": 100} for name, rate in rates.items()], "flags": []}


# --- the bus load, measured live ---------------------------------------------------------------


def test_the_live_bus_load_is_each_tasks_measured_rate_times_its_bytes_per_cycle(demo):
    rates = {"robot": 990.0, "traj": 500.0, "pid": 1001.0, "logger": 100.0}
    measured = bus.measured_live(demo, running(rates))
    predicted = bus_model.predict(demo, "joint_pid")
    assert measured.kind == "measured" and measured.configuration == "joint_pid"
    for load in measured.tasks:
        per_cycle = predicted.task(load.task).per_cycle_bytes
        assert load.per_cycle_bytes == per_cycle
        assert load.rate_bytes_per_s == pytest.approx(rates[load.task] * per_cycle)
        assert load.period == pytest.approx(1 / rates[load.task])
    assert measured.total == pytest.approx(sum(r * predicted.task(t).per_cycle_bytes for t, r in rates.items()))
    assert measured.share == pytest.approx(measured.total / predicted.bandwidth)


def test_at_the_nominal_rates_the_live_load_is_the_predicted_one(demo):
    predicted = bus_model.predict(demo, "joint_pid")
    measured = bus.measured_live(demo, running({load.task: 1 / load.period for load in predicted.tasks}))
    assert measured.total == pytest.approx(predicted.total)


@pytest.mark.parametrize("state", ["ERROR", "OFF", "KILLED"])
def test_a_task_that_is_not_on_moves_nothing_on_the_bus_now(demo, state):
    measured = bus.measured_live(demo, running({"robot": 1000.0, "traj": 500.0, "pid": 1000.0, "logger": 100.0},
                                               {"logger": state}))
    assert measured.task("logger").rate_bytes_per_s == 0.0 and math.isinf(measured.task("logger").period)
    assert measured.task("pid").rate_bytes_per_s > 0


def test_a_task_the_status_does_not_list_ran_no_cycle(demo):
    measured = bus.measured_live(demo, running({"robot": 1000.0}))
    assert [load.task for load in measured.tasks] == ["robot", "traj", "pid", "logger"]
    assert measured.task("traj").rate_bytes_per_s == 0.0


def test_a_configuration_the_file_lacks_is_refused_by_name(demo):
    with pytest.raises(bus_model.BusModelError, match="no configuration 'elsewhere'"):
        bus.measured_live(demo, running({}, configuration="elsewhere"))


# --- the arm's joint frames ------------------------------------------------------------------------


@pytest.mark.parametrize("robot", ["puma560", "redundant7"])
def test_the_arms_tool_frame_is_the_product_of_its_dh_transforms(robot):
    description = registry.load(registry.ROBOTS, robot)()
    frames = ArmFrames(*arm_tables(robot), robot)  # the ARM and EE its plant publishes
    for q in [description.q0, np.zeros(description.ndof), np.random.default_rng(7).uniform(-2, 2, description.ndof)]:
        positions = frames.positions(q)
        assert positions.shape == (description.ndof + 1, 3)
        np.testing.assert_allclose(positions[-1], dh_forward_kinematics(description.dh, q)[:3, 3], atol=1e-12)
        for i in range(description.ndof):  # joint i+1's frame is DH frame i: the product of the first i transforms
            np.testing.assert_allclose(positions[i], dh_forward_kinematics(description.dh[:i], q[:i])[:3, 3]
                                       if i else np.zeros(3), atol=1e-12)


def test_a_joint_vector_of_the_wrong_size_is_refused_with_the_arms_joints():
    frames = ArmFrames(*arm_tables("puma560"), "puma560")
    with pytest.raises(ValueError, match="arm 'puma560' has 6 joints, got 3 joint positions"):
        frames.positions([0.0, 0.0, 0.0])


@pytest.mark.parametrize(("arm", "ee", "message"), [
    (np.zeros((6, 4)), arm_tables("puma560")[1], r"ARM must have shape \(NDOF, 29\), got: \(6, 4\)"),
    (arm_tables("puma560")[0], np.zeros(7), r"EE must have shape \(8,\), got: \(7,\)"),
    (np.full((6, 29), np.nan), arm_tables("puma560")[1], "ARM and EE must be finite"),
])
def test_constants_that_are_not_an_arm_are_refused_with_the_arms_name(arm, ee, message):
    with pytest.raises(ValueError, match=rf"^arm 'puma560': {message}"):
        ArmFrames(arm, ee, "puma560")


# --- what the monitor reads of a file ------------------------------------------------------------


def test_the_layout_offers_the_tunable_parameters_with_the_files_values(demo):
    layout = monitor_layout(demo)
    assert layout["tasks"]["pid"]["tunable"] == {"kp": 400, "kd": 40, "ki": 10}
    assert layout["tasks"]["robot"]["tunable"] == {} and layout["tasks"]["logger"]["module"] == "data_logger"
    assert layout["variables"]["q_m"]["shape"] == [6] and layout["variables"]["ARM"]["shape"] == [6, 29]
    assert layout["variables"]["EE"]["shape"] == [8]
    assert layout["configurations"] == {"joint_pid": ["robot", "traj", "pid", "logger"]}
    assert layout["plant"] == "puma560"


# --- the routes ----------------------------------------------------------------------------------


class StatusLink:
    """A unit test's run: the status reply it is given, and a real table made by the test (or none: no run)."""

    def __init__(self, status: dict[str, Any] | None, table: str | None = None) -> None:
        self.status = status
        self.table = table

    def request(self, command: str, arguments: dict[str, Any], timeout: float) -> dict[str, Any]:
        if self.status is None:
            raise NoRun("no subsystem is running (no live state variable table of yours in /dev/shm): "
                        "start one with `pbo run FILE`")
        return self.status

    def open_table(self) -> TableView:
        if self.table is None:
            raise NoRun("no subsystem is running")
        return attach(self.table, "puma", "1234-abcdef")

    def runs(self) -> list[dict[str, Any]]:
        return []


@pytest.fixture
def blank_table(demo) -> Iterator[StateTable]:
    """A real table of the demo's layout, named like a run of this (live) process, as it is before any task started."""
    made = StateTable.create(TableLayout.of(demo), messages.table_name(f"mon{uuid.uuid4().hex[:6]}",
                                                                       f"{os.getpid()}-{uuid.uuid4().hex[:6]}"))
    yield made
    made.close()


@pytest.fixture
def table(blank_table) -> StateTable:
    """That table once the robot interface has published the arm's constants ARM and EE (the plant's PUMA 560)."""
    arm, ee = arm_tables("puma560")
    blank_table.write("ARM", arm, when=0.0)
    blank_table.write("EE", ee, when=0.0)
    return blank_table


def test_the_layout_route_answers_for_the_file_pbo_hmi_was_given():
    client = TestClient(create_app(StatusLink(None), TOKEN, str(DEMO)))
    reply = client.get("/api/monitor/layout", headers=BEARER).json()
    assert reply["ok"] and reply["subsystem"] == "puma" and reply["tasks"]["pid"]["tunable"]["kp"] == 400


def test_the_bus_route_gives_predicted_beside_measured_for_the_running_configuration(demo):
    rates = {"robot": 1000.0, "traj": 500.0, "pid": 1000.0, "logger": 50.0}
    client = TestClient(create_app(StatusLink(running(rates)), TOKEN))  # no file given: the run's own
    reply = client.get("/api/monitor/bus", headers=BEARER).json()
    assert reply["ok"] and reply["configuration"] == "joint_pid" and reply["file"] == str(DEMO)
    assert reply["predicted"]["kind"] == "predicted" and reply["measured"]["kind"] == "measured"
    assert reply["predicted"]["total"] == pytest.approx(bus_model.predict(demo, "joint_pid").total)
    logger = next(t for t in reply["measured"]["tasks"] if t["task"] == "logger")
    assert logger["rate_bytes_per_s"] == pytest.approx(50.0 * bus_model.predict(demo, "joint_pid").task("logger").per_cycle_bytes)


@pytest.mark.parametrize(("path", "status"), [("/api/monitor/bus", 404), ("/api/monitor/layout", 404)])
def test_without_a_run_or_a_file_the_monitor_routes_say_so(path, status):
    client = TestClient(create_app(StatusLink(None), TOKEN))
    response = client.get(path, headers=BEARER)
    assert response.status_code == status and response.json()["ok"] is False
    assert "no subsystem is running" in response.json()["error"] or "no subsystem file" in response.json()["error"]


def test_the_arm_stream_sends_the_joint_frames_of_q_m_in_the_table(table, demo):
    q = np.array([0.3, -0.5, 0.5, 0.2, 0.4, 0.2])
    table.write("q_m", q, when=1.0)
    client = TestClient(create_app(StatusLink(running({}), table.name), TOKEN, str(DEMO)))
    with client.websocket_connect("/api/streams/arm?rate=50", headers=BEARER) as stream:
        head = stream.receive_json()
        assert (head["ok"], head["arm"], head["ndof"], head["joints"]) == (True, "puma560", 6, "q_m")
        message = stream.receive_json()
    np.testing.assert_allclose(message["frames"], ArmFrames(*arm_tables("puma560")).positions(q), atol=1e-12)
    description = registry.load(registry.ROBOTS, "puma560")()
    np.testing.assert_allclose(message["frames"][-1], dh_forward_kinematics(description.dh, q)[:3, 3], atol=1e-12)
    assert message["q"] == q.tolist()


def test_the_arm_stream_draws_the_arm_in_the_table_not_the_one_the_file_names(table):
    """Whatever robot the file's plant names, the drawing is of the ARM and EE the run published."""
    scaled = arm_tables("puma560")[0].copy()
    scaled[:, Arm.POSITION] *= 2.0  # every joint twice as far from its parent: only the table says so
    table.write("ARM", scaled, when=1.0)
    q = np.array([0.3, -0.5, 0.5, 0.2, 0.4, 0.2])
    table.write("q_m", q, when=1.0)
    client = TestClient(create_app(StatusLink(running({}), table.name), TOKEN, str(DEMO)))
    with client.websocket_connect("/api/streams/arm?rate=50", headers=BEARER) as stream:
        stream.receive_json()
        message = stream.receive_json()
    drawn = np.array(message["frames"])
    np.testing.assert_allclose(drawn, ArmFrames(scaled, arm_tables("puma560")[1]).positions(q), atol=1e-12)
    assert not np.allclose(drawn, ArmFrames(*arm_tables("puma560")).positions(q), atol=1e-3)


def test_the_arm_stream_refuses_before_the_robot_interface_published_the_arm(blank_table):
    client = TestClient(create_app(StatusLink(running({}), blank_table.name), TOKEN, str(DEMO)))
    with client.websocket_connect("/api/streams/arm", headers=BEARER) as stream:
        first = stream.receive_json()
        assert first["ok"] is False
        assert first["error"].startswith("no arm to draw: the robot interface of 'puma' has not published ARM yet")
        with pytest.raises(WebSocketDisconnect) as closed:
            stream.receive_json()
    assert closed.value.code == 1008


@pytest.mark.parametrize(("query", "refusal"), [
    ("rate=60", "rate must be > 0 and at most 50 Hz, got: 60 Hz; ask for 50 or less"),
    ("q=q_x", "no variable 'q_x' in 'puma' to draw the arm from"),
    ("q=tau_u&rate=1", None),  # a variable of the arm's size draws, whatever it holds
])
def test_the_arm_stream_refuses_what_it_cannot_draw_with_a_message(table, query, refusal):
    client = TestClient(create_app(StatusLink(running({}), table.name), TOKEN, str(DEMO)))
    with client.websocket_connect(f"/api/streams/arm?{query}", headers=BEARER) as stream:
        first = stream.receive_json()
        if refusal is None:
            assert first["ok"] is True
            return
        assert first["ok"] is False and first["error"].startswith(refusal)
        with pytest.raises(WebSocketDisconnect) as closed:
            stream.receive_json()
    assert closed.value.code == 1008


def test_the_arm_stream_is_behind_the_token(table):
    client = TestClient(create_app(StatusLink(running({}), table.name), TOKEN, str(DEMO)))
    with (pytest.raises(WebSocketDisconnect),
          client.websocket_connect("/api/streams/arm", headers={"Authorization": "Bearer wrong"})):
        pass


def test_the_monitors_files_are_served_and_packaged():
    client = TestClient(create_app(StatusLink(None), TOKEN))
    for path in ("js/monitor.js", "js/monitor/plot.js", "js/monitor/arm.js", "css/monitor.css"):
        assert client.get(f"/static/{path}", headers=BEARER).status_code == 200, path
    assert '"hmi/js/*/*"' in (REPO / "pyproject.toml").read_text()
