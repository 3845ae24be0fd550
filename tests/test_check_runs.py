"""A file that checks clean runs (issue 35): a property over random subsystem files.

Hypothesis builds subsystem files from the module and driver library, within bounds that keep one
example a few seconds: a plant or none, devices of every driver, a robot interface and tasks of
library modules with their ports now and then relinked, periods, RTPUs, configurations, a job and
an application. Whenever `pbo check` accepts a file, a short `pbo run --clock sim` of it must start,
turn its first configuration on and stop cleanly (exit 0): an init failure is a checker bug. Whenever
the checker refuses one, no error is its own (E9xx).

CI runs a few examples; `pytest tests/test_check_runs.py --hypothesis-profile=long` runs many
(the profile is registered in tests/conftest.py; docs/error-codes.md says how long it took). What it
found is kept below as regression cases, each a file the checker once accepted and `pbo run` refused.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st

from pbo_runtime.config.loader import check_file
from pbo_runtime.objects import registry
from tests.support import PBO, REPO

LONG = settings.default is settings.get_profile("long")  # --hypothesis-profile=long (tests/conftest.py), run by hand
EXAMPLES = settings.default.max_examples if LONG else 10
RUN_FOR = "0.02"  # simulated seconds once the configuration is on: starting and stopping is the point

PERIODS = ("0.5 ms", "1 ms", "2 ms", "5 ms", "10 ms")
CONDITIONS = ("max(abs(q_m - q_d)) < 1e-3", "q_m[0] > -10", "q_m[5] < 10", "q_m[6] < 1", "norm(qd_m) >= 0",
              "max(abs(q_m - EE)) < 1", "NDOF == 6", "x_m[2] > -1")
# Variables a relinked port may be given: the library's own names, one undeclared, one of another shape
POOL = ("q_m", "qd_m", "q_r", "qd_r", "q_d", "tau_u", "tau_g", "x_m", "x_d", "J", "EE", "qdd_r", "spare", "f_m")

# The library's tasks: (module, params, the device it opens or None)
TASKS: dict[str, tuple[str, dict[str, Any], str | None]] = {
    "robot": ("robot_torque", {}, "arm"),
    "robot_p": ("robot_position", {}, "arm"),
    "traj": ("joint_trajectory", {"max_velocity": 1.0}, None),
    "pid": ("pid_joint", {"kp": 400, "kd": 40}, None),
    "grav": ("gravity_compensation", {}, None),
    "fk": ("fk_jacobian", {}, None),
    "fpa_fk": ("fk_jacobian_spp", {"device": "fpa"}, "fpa"),
    "dls": ("damped_least_squares", {}, None),
    "rate": ("resolved_rate", {"gain": 2.0}, None),
    "integ": ("time_integrator", {}, None),
    "ik": ("inverse_kinematics", {}, None),
    "vision": ("visual_servoing", {"device": "cam"}, "cam"),
    "ball": ("trackball_input", {"script": [[0, 0, 0, 0, 0, 0, 0], [1, 0.01, 0, 0, 0, 0, 0]]}, None),
    "goal": ("goal_input", {}, None),
    "diff": ("differentiator", {}, None),
    "aux": ("analog_input", {"device": "adc0"}, "adc0"),
    "out": ("analog_output", {"device": "dac0"}, "dac0"),
    "ctc": ("combined", {"members": [{"module": "pid_joint", "params": {"kp": 900, "kd": 60, "gravity_feedforward": False},
                                      "ports": {"tau": "qdd_r"}}, {"module": "inverse_dynamics"}]}, None),
    "log": ("data_logger", {"variables": ["q_m"], "path": "run.mcap"}, None),
}
# Tasks that make a controller together: the robot interface, and what writes what it reads
CHAINS = (
    ("robot", "traj", "pid"), ("robot", "goal", "traj", "pid"), ("robot", "traj", "ctc"), ("robot", "traj", "pid", "grav"),
    ("robot_p", "traj"), ("robot_p", "fk", "dls", "integ"), ("robot_p", "fk", "rate", "integ"), ("robot_p", "ik"),
    ("robot_p", "fk", "vision", "dls", "integ"), ("robot_p", "fk", "ball", "dls", "integ"), ("robot_p", "fpa_fk", "dls", "integ"),
    ("robot_p", "fpa_fk", "rate", "integ"),
)
EXTRAS = ("log", "diff", "aux", "out", "fk", "grav")  # tasks that read what any chain writes, or nothing
DEVICES = {
    "arm": {"driver": "mujoco_arm", "exclusive": True},
    "fpa": {"driver": "spp"},
    "cam": {"driver": "camera"},
    "adc0": {"driver": "adc"},
    "dac0": {"driver": "dac", "exclusive": True},
    "ball": {"driver": "trackball", "source": "hmi"},
}
DECLARED = {  # variables a file may declare: what a reader of them needs when nothing writes them
    "q_d": {"type": "float64", "shape": ["NDOF"], "object": "joint_position", "initial": 0},
    "x_d": {"type": "float64", "shape": [6], "initial": [0.45, -0.15, 0.2, 0, 0, 0]},
    "v_in": {"type": "float64", "shape": [2]},
    "v_out": {"type": "float64", "shape": [2], "initial": 0},
    "z": {"type": "float64", "shape": [3], "initial": 0},
    "zd": {"type": "float64", "shape": [3]},
    "spare": {"type": "float64", "shape": [4]},
}
PORTS = {module: [p.name for p in registry.module_class(module).ports()] for module, _, _ in TASKS.values()}


# One mistake at most a file, so that about half of them check clean. Chances come from a Random
# Hypothesis seeds: it draws small integers far more often than one in n, the Random is fair.
MISTAKES = ("no plant", "no target", "no device", "arm mode", "undeclared", "channels", "relink", "param", "rtpu", "subset")
MISTAKE_RATE = 0.4


@st.composite
def subsystem_files(draw: st.DrawFn) -> dict[str, Any]:
    """A random subsystem file, as the mapping its YAML holds: mostly right, now and then not."""
    chance = draw(st.randoms(use_true_random=True))
    mistake = chance.choice(MISTAKES) if chance.random() < MISTAKE_RATE else None
    rtpus = [f"rtpu{i}" for i in range(draw(st.integers(1, 3)))]
    doc: dict[str, Any] = {"subsystem": "prop", "rtpus": rtpus}
    chain = draw(st.sampled_from(CHAINS))
    extras = draw(st.lists(st.sampled_from(EXTRAS), max_size=3, unique=True))
    names = list(dict.fromkeys(chain + tuple(e for e in extras if not (e == "fk" and "fpa_fk" in chain))))
    if mistake != "no plant":
        plant: dict[str, Any] = {"model": draw(st.sampled_from(("puma560", "puma560", "redundant7"))), "timestep": "1 ms"}
        if ("vision" in names and mistake != "no target") or chance.random() < 0.25:
            plant["target"] = {"center": [0.45, -0.15, 0.1], "radius": 0.05, "period": 8}
        doc["plant"] = plant
    needed = {TASKS[n][2] for n in names} - {None}
    devices = {name: dict(spec) for name, spec in DEVICES.items()
               if (name in needed and mistake != "no device") or chance.random() < 0.2}
    if "arm" in devices:
        devices["arm"]["mode"] = "position" if "robot_p" in names else "torque"
        if mistake == "arm mode":
            devices["arm"]["mode"] = draw(st.sampled_from(("torque", "position", "velocity")))
    doc["devices"] = devices
    wanted = {"q_d"} if "traj" in names else set()
    wanted |= {"x_d"} if {"dls", "rate", "ik"} & set(names) and not {"vision", "ball"} & set(names) else set()
    wanted |= {"v_out"} if "out" in names else set()
    wanted |= {"z", "zd"} if "diff" in names else set()
    wanted |= {"v_in"} if "aux" in names else set()
    doc["variables"] = {name: dict(spec) for name, spec in DECLARED.items()
                        if (name in wanted and mistake != "undeclared") or chance.random() < 0.2}
    tasks: dict[str, Any] = {}
    for name in names:
        module, params, device = TASKS[name]
        task: dict[str, Any] = {"module": module, "rtpu": draw(st.sampled_from(rtpus)),
                                "period": "1 ms" if name.startswith("robot") else draw(st.sampled_from(PERIODS))}
        if name.startswith("robot"):
            task["critical"] = True
        if params:
            task["params"] = {key: (list(value) if isinstance(value, list) else value) for key, value in params.items()}
        if device is not None:
            task["resources"] = [device]
        if module == "analog_input":
            task["ports"] = {"v": "v_in"}
            task["resources"] = [{"device": "adc0",
                                  "channels": "6-8" if mistake == "channels" else draw(st.sampled_from(("6-7", "0-1")))}]
        if module == "analog_output":
            task["ports"] = {"v": "v_out"}
            task["resources"] = [{"device": "dac0", "channels": "0-1"}]
        if module == "differentiator":
            task["ports"] = {"z": "z", "zd": "zd"}
        if module == "data_logger":
            task["params"]["variables"] = draw(st.lists(st.sampled_from(("q_m", "qd_m", "NDOF", "ARM")), min_size=1,
                                                        max_size=3, unique=True))
        if mistake == "relink" and PORTS[module] and chance.random() < 0.5:  # a port relinked to another variable
            task.setdefault("ports", {})[draw(st.sampled_from(PORTS[module]))] = draw(st.sampled_from(POOL))
        if mistake == "param" and chance.random() < 0.5:  # a parameter out of its range, or of the wrong kind
            task.setdefault("params", {})[draw(st.sampled_from(("kp", "gain", "max_velocity", "frame", "max_lead")))] = draw(
                st.sampled_from((-1, 1e9, "ee", "link9", 0, 0.5)))
        if mistake == "rtpu" and chance.random() < 0.5:
            task["rtpu"] = "rtpu9"
        tasks[name] = task
    doc["tasks"] = tasks
    doc["configurations"] = {"first": names if mistake != "subset" else
                             draw(st.lists(st.sampled_from(names), min_size=1, max_size=len(names), unique=True))}
    if chance.random() < 0.25:  # another configuration: a chain of its own, or the first's tasks less its extras
        doc["configurations"]["second"] = list(chain)
    if draw(st.booleans()):
        job: dict[str, Any] = {"configuration": "first", "timeout": "1 s"}
        if "q_d" in doc["variables"] and "traj" in names:
            job["object"] = "q_d"
        if draw(st.booleans()):
            job["post"] = draw(st.sampled_from(CONDITIONS))
        doc["jobs"] = {"go": job}
        if "object" in job and draw(st.booleans()):
            doc["applications"] = {"tour": [{"go": {"q_d": [0.1, -0.2, 0.2, 0, 0.1, 0]}}] if draw(st.booleans()) else ["go"]}
    return doc


def _write(folder: Path, doc: dict[str, Any]) -> Path:
    path = folder / "prop.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120))
    return path


def check_then_run(folder: Path, doc: dict[str, Any]) -> None:
    """The property: refused with the checker's own codes only, or accepted and run cleanly."""
    path = _write(folder, doc)
    result = check_file(path)
    for diagnostic in [*result.errors, *result.warnings]:
        assert not diagnostic.code.startswith("E9"), diagnostic.format()
    if result.errors:
        event(f"refused: {result.errors[0].code}")
        return
    event("accepted: run")
    warned = {w.code for w in result.warnings}
    arguments = ["--static"] if "W601" in warned else []  # W601: a dynamic run refuses it
    run = subprocess.run([*PBO, "run", str(path), "--clock", "sim", "--duration", RUN_FOR, "--no-live",
                          "--out", str(folder / "run"), *arguments], capture_output=True, text=True, cwd=folder, timeout=300)
    output = run.stdout + run.stderr
    told = "\n".join(line for line in output.splitlines() if re.search(r"error|fault|refused|failed|Traceback", line))
    said = f"{path.read_text()}\n--- pbo run said:\n{told}\n{run.stderr[-2000:]}"
    assert "Traceback" not in output, said
    if "W504" in warned:  # the warning said the simulated clock refuses it, and why
        assert run.returncode != 0 and "not whole multiples" in output, said
        return
    assert run.returncode == 0, said
    assert re.search(r"configuration '\w+' on|simulated", run.stdout + run.stderr), said


# Found by the property, each once accepted by `pbo check` and refused by `pbo run` at init
ARM_WITHOUT_A_PLANT = {  # E611: the arm's driver attaches to the plant's registers
    "subsystem": "prop", "rtpus": ["rtpu0"], "devices": {"arm": {"driver": "mujoco_arm", "mode": "torque"}},
    "tasks": {"robot": {"module": "robot_torque", "rtpu": "rtpu0", "period": "1 ms", "resources": ["arm"]},
              "grav": {"module": "gravity_compensation", "rtpu": "rtpu0", "period": "1 ms", "ports": {"tau_g": "tau_u"}}},
    "configurations": {"first": ["robot", "grav"]}}

OFF_THE_PLANT_GRID = {  # W504: --clock sim releases tasks on the plant's 1 ms steps, never at 0.5 ms
    "subsystem": "prop", "rtpus": ["rtpu0"], "plant": {"model": "puma560", "timestep": "1 ms"},
    "devices": {"arm": {"driver": "mujoco_arm", "mode": "torque"}},
    "variables": {"q_d": {"type": "float64", "shape": ["NDOF"], "object": "joint_position", "initial": 0}},
    "tasks": {"robot": {"module": "robot_torque", "rtpu": "rtpu0", "period": "1 ms", "resources": ["arm"]},
              "traj": {"module": "joint_trajectory", "rtpu": "rtpu0", "period": "0.5 ms"},
              "pid": {"module": "pid_joint", "rtpu": "rtpu0", "period": "0.5 ms"}},
    "configurations": {"first": ["robot", "traj", "pid"]}}


@pytest.mark.multiprocess
@pytest.mark.timeout(0 if LONG else 600)  # the long profile runs for an hour; each run has its own net below
@example(doc=ARM_WITHOUT_A_PLANT)
@example(doc=OFF_THE_PLANT_GRID)
@settings(max_examples=EXAMPLES, deadline=None, derandomize=not LONG,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture, HealthCheck.data_too_large])
@given(doc=subsystem_files())
def test_a_file_the_checker_accepts_runs_and_one_it_refuses_gets_its_own_codes(tmp_path_factory: pytest.TempPathFactory,
                                                                               doc: dict[str, Any]) -> None:
    check_then_run(tmp_path_factory.mktemp("prop"), doc)


def test_the_reference_of_the_property_is_a_real_library() -> None:
    """Every module and driver the strategy draws is registered (a rename would silently shrink it)."""
    assert {module for module, _, _ in TASKS.values()} <= set(registry.names(registry.MODULES))
    assert {spec["driver"] for spec in DEVICES.values()} <= set(registry.names(registry.DRIVERS))
    assert REPO.is_dir()
