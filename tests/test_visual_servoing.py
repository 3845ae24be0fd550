"""Visual servoing (TR Figures 12 and 13): the plant's target, the camera, the interface module.

In one process: the plant moves its target along the circle of its `target:` option and the
camera driver reads it (plant stepped by hand); the camera's noise and latency; the visual
servoing module, driven through a real Task on a real table, writes target + offset; and, on the
poses the demo's path visits, resolved rate's joint speeds blow up at the wrist singularity
while damped least squares' stay bounded. The end-to-end runs of configs/visual_servoing.yaml
need the module and the driver registered as entry points and are skipped until they are.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import yaml

from drivers.mujoco_arm.plant import MujocoArmPlant
from drivers.mujoco_arm.registers import DeviceError
from drivers.robots import robot
from drivers.vision.camera import VisionCamera
from modules._robot_model import END_EFFECTOR_FRAME, frame_id, frame_pose_and_jacobian
from modules.damped_least_squares import DampedLeastSquares
from modules.resolved_rate import ResolvedRate
from modules.visual_servoing import VisualServoing
from pbo_runtime import ParamError, PortBasedObject, Status, read_log
from pbo_runtime.config.model import DeviceSpec, TaskSpec
from pbo_runtime.objects import registry
from pbo_runtime.table.table import StateTable, TaskState
from pbo_runtime.task.lifecycle import Task
from tests.support import (
    NO_WATCHDOG,
    PBO,
    REPO,
    arm_constants,
    arm_tables,
    assert_nothing_left,
    dh_pinocchio_model,
    task_spec,
    unique_name,
    variables,
)

TIMESTEP = 0.001
CONFIG = REPO / "configs" / "visual_servoing.yaml"
DEMO = yaml.safe_load(CONFIG.read_text())
DEMO_Q0 = np.array(DEMO["plant"]["q0"])
DEMO_TARGET = DEMO["plant"]["target"]
DEMO_OFFSET = np.array(DEMO["tasks"]["vision"]["params"]["offset"])
CIRCLE = {"center": [0.4, -0.1, 0.2], "radius": 0.1, "period": 2.0}
CAMERA = DeviceSpec("camera", "camera", False, {})


@pytest.fixture
def make_plant() -> Iterator:
    made: list[MujocoArmPlant] = []

    def make(target: dict | None = CIRCLE, **options) -> MujocoArmPlant:
        if target is not None:
            options["target"] = target
        plant = MujocoArmPlant(unique_name("plant"), "puma560", TIMESTEP, {**NO_WATCHDOG, **options})
        made.append(plant)
        return plant

    yield make
    for plant in made:
        plant.close()


@pytest.fixture
def plant(make_plant) -> MujocoArmPlant:
    return make_plant()


@pytest.fixture
def make_camera(plant) -> Iterator:
    opened: list[VisionCamera] = []

    def make(**options) -> VisionCamera:
        camera = VisionCamera(plant.name, options)
        opened.append(camera)
        return camera

    yield make
    for camera in opened:
        camera.close()


def circle(t: float, center=CIRCLE["center"], radius=CIRCLE["radius"], period=CIRCLE["period"], phase=0.0):
    angle = 2 * np.pi * t / period + phase
    return np.array(center) + radius * np.array([np.cos(angle), np.sin(angle), 0.0])


def run(plant: MujocoArmPlant, seconds: float) -> None:
    for _ in range(round(seconds / plant.timestep)):
        plant.step()


# the plant's target and the camera ---------------------------------------------------------------


def test_the_plant_moves_the_target_on_its_circle_and_the_camera_reads_it(plant, make_camera):
    camera = make_camera()
    x = np.zeros(6)
    assert camera.read_target(x) == 0.0
    np.testing.assert_allclose(x, [*circle(0.0), 0, 0, 0], rtol=0, atol=1e-12)
    for seconds in (0.25, 0.25, 0.5, 0.3):
        run(plant, seconds)
        t = camera.read_target(x)
        assert t == pytest.approx(plant.sim_time, abs=1e-12)
        np.testing.assert_allclose(x[:3], circle(t), rtol=0, atol=1e-12)
        np.testing.assert_array_equal(x[3:], 0.0)
        # the marker the plant shows is where the camera says it is
        np.testing.assert_allclose(plant.data.mocap_pos[0], x[:3], rtol=0, atol=1e-12)
    assert plant.model.nq == 6 and plant.model.nv == 6  # the marker adds no joint to the arm


def test_the_target_keeps_its_orientation_and_phase(make_plant):
    plant = make_plant(dict(CIRCLE, phase=np.pi / 2, orientation=[0.0, 0.0, 0.5]))
    camera = VisionCamera(plant.name, {})
    try:
        x = np.zeros(6)
        run(plant, 0.5)
        t = camera.read_target(x)
        np.testing.assert_allclose(x, [*circle(t, phase=np.pi / 2), 0, 0, 0.5], rtol=0, atol=1e-12)
        np.testing.assert_allclose(plant.data.mocap_quat[0], [np.cos(0.25), 0, 0, np.sin(0.25)], atol=1e-12)
    finally:
        camera.close()


def test_the_arm_does_not_feel_the_target(make_plant):
    with_target, without = make_plant(), make_plant(target=None)
    for p in (with_target, without):
        p._registers.words[7] = 0  # release the brakes, no command: the arm falls the same way
        run(p, 0.2)
    np.testing.assert_array_equal(with_target.data.qpos, without.data.qpos)


def test_a_camera_on_a_plant_without_target_is_refused(make_plant):
    plant = make_plant(target=None)
    with pytest.raises(DeviceError, match=r"the plant has no target to see; give the plant the option target:"):
        VisionCamera(plant.name, {})


@pytest.mark.parametrize(
    ("target", "message"),
    [
        ({"center": [0, 0, 0], "radius": 0.1}, r"^plant option target needs period \(a circle"),
        (dict(CIRCLE, speed=1), r"^unknown plant target option\(s\) \['speed'\]; valid options: center, radius, period"),
        (dict(CIRCLE, radius=-0.1), r"^plant option target.radius must be a finite number > 0, got: -0.1$"),
        (dict(CIRCLE, period=0), r"^plant option target.period must be a finite number > 0, got: 0$"),
        (dict(CIRCLE, center=[1, 2]), r"^plant option target.center must be 3 finite numbers, got: \[1, 2\]$"),
        ([1, 2, 3], r"^plant option target must be a mapping"),
    ],
)
def test_bad_target_options_are_refused(make_plant, target, message):
    with pytest.raises(ValueError, match=message):
        make_plant(target)


def test_latency_delays_the_pose_by_that_many_frames(plant, make_camera):
    prompt, late = make_camera(), make_camera(latency=3)
    seen: list[tuple[float, np.ndarray]] = []
    x, y = np.zeros(6), np.zeros(6)
    for k in range(8):
        t = prompt.read_target(x)
        t_late = late.read_target(y)
        seen.append((t, x.copy()))
        expected_t, expected_x = seen[max(0, k - 3)]
        assert t_late == expected_t
        np.testing.assert_array_equal(y, expected_x)
        run(plant, 0.01)
    assert late.frames == 8


def test_noise_is_gaussian_of_the_given_size_and_seeded(plant, make_camera):
    sigma = 0.002
    a, b, other = make_camera(noise=sigma, seed=7), make_camera(noise=sigma, seed=7), make_camera(noise=sigma, seed=8)
    xa, xb, xo = np.zeros(6), np.zeros(6), np.zeros(6)
    errors = []
    for _ in range(2000):
        t = a.read_target(xa)
        b.read_target(xb)
        other.read_target(xo)
        np.testing.assert_array_equal(xa, xb)  # same seed, same noise
        errors.append(xa[:3] - circle(t))
        np.testing.assert_array_equal(xa[3:], 0.0)  # orientation is not noised
        plant.step()
    errors = np.array(errors)
    assert np.abs(errors.mean(axis=0)).max() < 4 * sigma / np.sqrt(2000)
    np.testing.assert_allclose(errors.std(axis=0), sigma, rtol=0.08)
    assert not np.array_equal(xa, xo)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"noise": -0.1}, r"^camera option noise must be a number in \[0, 10\] \(standard deviation, m\), got: -0.1$"),
        ({"noise": float("nan")}, r"^camera option noise must be a number in \[0, 10\]"),
        ({"noise": float("inf")}, r"^camera option noise must be a number in \[0, 10\]"),
        ({"noise": "1 mm"}, r"^camera option noise must be a number in \[0, 10\] .*got: '1 mm'$"),
        ({"latency": -1}, r"^camera option latency must be a whole number of frames in \[0, 10000\], got: -1$"),
        ({"latency": 10**12}, r"^camera option latency must be a whole number of frames in \[0, 10000\], got: 1000000000000$"),
        ({"latency": 1.5}, r"^camera option latency must be a whole number of frames in \[0, 10000\], got: 1.5$"),
        ({"latency": True}, r"^camera option latency must be a whole number of frames in \[0, 10000\], got: True$"),
        ({"seed": -3}, r"^camera option seed must be an integer in \[0, 4294967295\], got: -3$"),
        ({"blur": 1}, r"^unknown camera driver option\(s\) \['blur'\]; valid options: latency, noise, seed$"),
    ],
)
def test_invalid_camera_options_are_refused_with_clear_messages(plant, options, message):
    with pytest.raises(ValueError, match=message):
        VisionCamera(plant.name, options)


def test_read_target_allocates_nothing(plant, make_camera):
    import tracemalloc

    camera = make_camera(noise=0.001, latency=2)
    x = np.zeros(6)
    camera.read_target(x)
    tracemalloc.start()
    try:
        before = tracemalloc.take_snapshot()
        for _ in range(200):
            camera.read_target(x)
        after = tracemalloc.take_snapshot()
    finally:
        tracemalloc.stop()
    grown = sum(s.size_diff for s in after.compare_to(before, "filename") if "camera.py" in str(s.traceback))
    assert grown <= 0


# the visual servoing interface module ------------------------------------------------------------


@pytest.fixture
def table(make_table) -> StateTable:
    return make_table(variables(("x_m", "float64", (6,)), ("x_d", "float64", (6,))))


def vision_task(table: StateTable, plant: MujocoArmPlant, params: dict | None = None,
                device: DeviceSpec = CAMERA) -> tuple[Task, list[VisionCamera]]:
    opened: list[VisionCamera] = []

    def opener(spec: DeviceSpec, _task: TaskSpec) -> VisionCamera:
        camera = VisionCamera(plant.name, spec.options)
        opened.append(camera)
        return camera

    spec = dataclasses.replace(task_spec(VisualServoing, params=params, period=0.01), resources=("camera",))
    return Task(spec, VisualServoing, table, {}, devices={"camera": device}, opener=opener), opened


def test_the_module_writes_target_plus_offset_and_keeps_the_hands_orientation(table, plant):
    x_m = np.array([0.5, 0.0, 0.3, 0.1, -0.2, 0.3])
    table.write("x_m", x_m, when=0.0)
    task, opened = vision_task(table, plant, {"offset": [0.0, 0.01, 0.1]})
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0), task.last_error
    np.testing.assert_allclose(table.read("x_d")[0], [*(circle(0.0) + np.array([0, 0.01, 0.1])), 0.1, -0.2, 0.3], atol=1e-12)
    for k in range(1, 6):
        run(plant, 0.01)
        table.write("x_m", x_m + k, when=k * 0.01)  # the hand moves: the orientation stays the one at `on`
        assert task.run_cycle(k * 0.01) is Status.CONTINUE, task.last_error
        x_d = table.read("x_d")[0]
        np.testing.assert_allclose(x_d[:3], circle(plant.sim_time) + np.array([0, 0.01, 0.1]), rtol=0, atol=1e-12)
        np.testing.assert_array_equal(x_d[3:], x_m[3:])
    task.kill()
    assert [c.frames for c in opened] == [6] and task.state is TaskState.KILLED


def test_a_given_orientation_is_used_as_it_is(table, plant):
    task, _ = vision_task(table, plant, {"offset": [0.0, 0.0, 0.0], "orientation": [0.0, 3.0, 0.0]})
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0), task.last_error
    run(plant, 0.1)
    assert task.run_cycle(0.1) is Status.CONTINUE, task.last_error
    np.testing.assert_allclose(table.read("x_d")[0], [*circle(plant.sim_time), 0.0, 3.0, 0.0], atol=1e-12)
    task.kill()


def test_the_module_refuses_a_device_that_is_not_a_camera(table, plant):
    from drivers.mujoco_arm.driver import MujocoArmDriver

    opened = []

    def opener(spec: DeviceSpec, _task: TaskSpec):
        driver = MujocoArmDriver(plant.name, {"mode": "position"})
        opened.append(driver)
        return driver

    spec = dataclasses.replace(task_spec(VisualServoing, period=0.01), resources=("camera",))
    task = Task(spec, VisualServoing, table, {}, devices={"camera": CAMERA}, opener=opener)
    assert not task.spawn(0.0)
    assert "device 'camera' is not a camera (it has no read_target); give it driver: camera" in task.last_error


@pytest.mark.parametrize(
    ("params", "message"),
    [({"offset": [0, 0]}, "offset must be 3 finite numbers"), ({"orientation": [0, 1]}, "orientation must be 3 finite numbers")],
)
def test_bad_module_params_are_refused(params, message):
    with pytest.raises((ValueError, ParamError), match=message):
        VisualServoing.Params(**{k: tuple(v) for k, v in params.items()})


# the singularity on the demo's path: resolved rate vs damped least squares ----------------------

PUMA = robot("puma560")
PUMA_ARM, PUMA_EE = arm_tables("puma560")  # what its robot interface publishes
N = PUMA.ndof


def controller(make_table, module: type[PortBasedObject], params: dict) -> tuple[Task, StateTable]:
    table = make_table(variables(*arm_constants(N), ("q_m", "float64", (N,)), ("x_d", "float64", (6,)),
                                 ("qd_r", "float64", (N,))))
    table.write("NDOF", N, when=0.0)
    table.write("ARM", PUMA_ARM, when=0.0)
    table.write("EE", PUMA_EE, when=0.0)
    task = Task(task_spec(module, dims={"NDOF": N}, params=params), module, table, {"NDOF": N})
    assert task.spawn(0.0), task.last_error
    return task, table


def follow_the_demo_path(driver: tuple[Task, StateTable], shadow: tuple[Task, StateTable],
                         seconds: float = 4.0, dt: float = 0.002) -> dict:
    """The driver controller on the demo's target path (offset and start pose from the YAML), its
    qd_r integrated exactly (an ideal arm); the shadow controller sees the same q_m and x_d every
    cycle (the poses the path visits) but does not move the arm. Returns the largest joint speed
    each asks for, the smallest |q5| passed and the driver's largest position error after 0.2 s."""
    model = dh_pinocchio_model(PUMA.dh, PUMA.dyn)  # the ideal arm, modelled apart from the controllers' ARM table
    data, frame = model.createData(), frame_id(model, END_EFFECTOR_FRAME)
    x, jacobian = np.zeros(6), np.zeros((6, N))
    q = DEMO_Q0.copy()
    frame_pose_and_jacobian(model, data, frame, q, x, jacobian)
    orientation = x[3:].copy()
    target = {k: DEMO_TARGET[k] for k in ("center", "radius", "period", "phase")}
    worst = {"driver": 0.0, "shadow": 0.0, "q5": np.inf, "error": 0.0}
    for k in range(round(seconds / dt)):
        t = k * dt
        x_d = np.r_[circle(t, **target) + DEMO_OFFSET, orientation]
        for role, (task, table) in (("shadow", shadow), ("driver", driver)):
            table.write("q_m", q, when=t)
            table.write("x_d", x_d, when=t)
            assert (task.turn_on(t) if k == 0 else task.run_cycle(t)) in (True, Status.CONTINUE), task.last_error
            worst[role] = max(worst[role], float(np.abs(table.read("qd_r")[0]).max()))
        frame_pose_and_jacobian(model, data, frame, q, x, jacobian)
        if t > 0.2:
            worst["error"] = max(worst["error"], float(np.linalg.norm(x_d[:3] - x[:3])))
        q = q + driver[1].read("qd_r")[0] * dt
        worst["q5"] = min(worst["q5"], abs(q[4]))
    driver[0].kill()
    shadow[0].kill()
    return worst


def test_at_the_wrist_singularity_dls_keeps_joint_speeds_bounded_and_resolved_rate_does_not(make_table):
    """DLS drives the (ideal) arm along the demo's path straight through q5 = 0; on the same poses
    and desired poses resolved rate asks for joint speeds two orders of magnitude larger."""
    no_cap = 1e9  # rad/s: let each controller ask for what it computes
    dls = controller(make_table, DampedLeastSquares, {
        "gain": 10, "max_damping": 0.05, "manipulability_threshold": 0.01, "max_joint_speed": no_cap})
    ik = controller(make_table, ResolvedRate, {"gain": 10, "max_joint_speed": no_cap})
    worst = follow_the_demo_path(dls, ik)
    assert worst["q5"] < 0.01, worst  # the path takes the wrist through its singularity
    assert worst["driver"] < 2.5, worst  # DLS: bounded, |qd_r| <= gain |e| / (2 lambda)
    assert worst["error"] < 0.04, worst  # and the hand still follows the target
    assert worst["shadow"] > 100 * worst["driver"], worst  # J^+ amplifies by 1 / sigma_min


# end to end (needs the entry points) ---------------------------------------------------------------

REGISTERED = "visual_servoing" in registry.names(registry.MODULES) and "camera" in registry.names(registry.DRIVERS)
needs_entry_points = pytest.mark.skipif(
    not REGISTERED, reason="visual_servoing (pbo.modules) and camera (pbo.drivers) are not registered in pyproject.toml yet"
)


def pbo_run(tmp_path: Path, *arguments: str) -> tuple[subprocess.CompletedProcess, dict]:
    report_path = tmp_path / "report.json"
    done = subprocess.run([*PBO, "run", str(CONFIG), "--no-live", "--clock", "sim", "--report", str(report_path), *arguments],
                          cwd=tmp_path, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stdout + done.stderr
    return done, json.loads(report_path.read_text())


@needs_entry_points
@pytest.mark.multiprocess
def test_dls_tracks_the_target_through_the_wrist_singularity(tmp_path):
    _done, report = pbo_run(tmp_path, "--config", "dls", "--duration", "4")
    assert report["stopped_by"] == "duration" and report["failure"] == ""
    x_m = np.array(report["variables"]["x_m"]["value"])
    x_d = np.array(report["variables"]["x_d"]["value"])
    # 4 s: past the singularity (1.6-2.2 s into the lap); the lag of a 10/s loop at 9.4 cm/s is ~1 cm
    assert np.linalg.norm(x_m[:3] - x_d[:3]) < 0.03, f"hand at {x_m[:3]}, wanted {x_d[:3]}"
    assert np.linalg.norm(x_d[:3] - DEMO_OFFSET - np.array(DEMO_TARGET["center"])) == pytest.approx(
        DEMO_TARGET["radius"], abs=0.01)  # x_d is on the target's circle, lifted by the offset
    assert all(report["states_at_stop"][name] == "ON" for name in ("robot", "fk", "vision", "dls", "integ"))
    assert_nothing_left(report)


@needs_entry_points
@pytest.mark.multiprocess
def test_switching_between_ik_and_dls_while_servoing_completes(tmp_path):
    _done, report = pbo_run(tmp_path, "--alternate", "ik,dls", "--switches", "4", "--interval", "1")
    assert len(report["switches"]) == 4
    assert [s["to"] for s in report["switches"]] == ["dls", "ik", "dls", "ik"]
    assert report["failure"] == ""
    assert_nothing_left(report)


@needs_entry_points
@pytest.mark.multiprocess
def test_through_the_singularity_dls_bounds_the_joint_speeds_where_plain_ik_does_not(tmp_path):
    """TR Figures 12/13 in real processes: each controller alone, with the speed cap lifted, over
    the same 4 s lap (the wrist singularity is 1.6-2.2 s in). Deterministic on the simulated clock."""
    uncapped = tmp_path / "uncapped.yaml"
    uncapped.write_text(CONFIG.read_text().replace("max_joint_speed: 3}", "max_joint_speed: 1000}"))
    peak = {}
    for controller in ("ik", "dls"):
        done = subprocess.run([*PBO, "run", str(uncapped), "--config", controller, "--clock", "sim", "--duration", "4",
                               "--no-live", "--out", str(tmp_path / controller)], cwd=tmp_path, capture_output=True,
                              text=True, timeout=240)
        assert done.returncode == 0, done.stdout + done.stderr
        log = read_log(tmp_path / controller / "visual_servoing.mcap")
        speeds = np.abs(log["qd_m"]).max(axis=1)
        peak[controller] = (speeds.max(), log["time"][speeds.argmax()])
    ik_speed, ik_when = peak["ik"]
    dls_speed, _ = peak["dls"]
    assert 1.6 <= ik_when <= 2.2, f"plain IK peaks at {ik_when:.2f} s, not at the singularity"
    assert dls_speed < 2.5
    assert ik_speed > 2 * dls_speed, f"IK peak {ik_speed:.2f} rad/s vs DLS {dls_speed:.2f} rad/s"
