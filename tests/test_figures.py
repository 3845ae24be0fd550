"""Figures 10, 12 and 13 of the technical report as published, run end to end on the simulated clock.

Each runs the shipped configuration (under a subsystem name of its own) in real processes and
checks what the report claims of it: the Cartesian teleoperation follows the trackball's pose
(Figure 10), and damped least squares keeps the joint speeds bounded as the hand is servoed
through the wrist singularity (Figure 13), where inverse kinematics, run the same way, does not
(Figure 12). Figure 14's claim (computed torque tracks at least 5x better than PID) is
tests/test_combined.py's.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from pbo_runtime import read_log
from tests.support import PBO, REPO, assert_nothing_left, config_copy

pytestmark = pytest.mark.multiprocess

CONFIGS = REPO / "configs"


def run_sim(config: Path, folder: Path, *arguments: str) -> dict:
    """`pbo run` on the simulated clock; the run's report (asserting it exited 0)."""
    report_path = folder / "report.json"
    done = subprocess.run([*PBO, "run", str(config), "--no-live", "--clock", "sim", "--report", str(report_path),
                           "--out", str(folder / "out"), *arguments], cwd=folder, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    report = json.loads(report_path.read_text())
    assert report["failure"] == "" and report["faults"] == [], report
    return report


def test_figure_10_as_published_teleoperates_the_hand_through_inverse_dynamics(tmp_path):
    """Trackball -> Cartesian interpolator -> Cartesian controller -> inverse dynamics -> arm."""
    config = config_copy(CONFIGS / "cartesian_teleop.yaml", tmp_path, "lib_fig10")
    report = run_sim(config, tmp_path, "--duration", "5.5")
    assert report["configuration"] == "fig10"  # the default: the first in the file
    assert [t for t, state in report["states_at_stop"].items() if state == "ON"] == [
        "robot", "fk", "trackball", "interp", "cart", "idyn", "log10"]
    assert report["variables"]["tau_u"]["writer"] == "idyn"
    log = read_log(tmp_path / "out" / "fig10.mcap")
    moved = log["x_d"][-1, :3] - log["x_d"][0, :3]
    assert moved == pytest.approx([0.05, 0.0, 0.05], abs=1e-3)  # the script: 5 cm along x, then 5 cm up
    following = np.linalg.norm(log["x_m"][:, :3] - log["x_d"][:, :3], axis=1)
    assert following.max() < 0.003, f"the hand fell {following.max() * 1000:.1f} mm behind the trackball"
    assert following[-1] < 1e-4  # and is there once the trackball stops
    assert_nothing_left(report)


def servo_run(folder: Path, configuration: str) -> np.ndarray:
    """Figure 12 or 13 alone for one 8 s lap of the target; the data logger's rows."""
    config = config_copy(CONFIGS / "visual_servoing.yaml", folder, f"lib_{configuration}")
    report = run_sim(config, folder, "--config", configuration, "--duration", "8")
    assert_nothing_left(report)
    return read_log(folder / "out" / "visual_servoing.mcap")


def test_figures_12_and_13_through_the_wrist_singularity_damped_least_squares_keeps_joint_speeds_bounded(tmp_path):
    """TR §4.4: Figure 13's damped least squares keeps the arm from rushing through the singularity
    that Figure 12's inverse kinematics takes at speed. Same lap, same target, deterministic."""
    logs = {}
    for configuration in ("fig12", "fig13"):
        (tmp_path / configuration).mkdir()
        logs[configuration] = servo_run(tmp_path / configuration, configuration)
    peak, closest = {}, {}
    for configuration, log in logs.items():
        closest[configuration] = np.linalg.svd(log["J"], compute_uv=False)[:, -1].min()
        peak[configuration] = np.abs(log["qd_m"]).max()
    assert max(closest.values()) < 1e-3, f"the wrist came no nearer its singularity than sigma_min {closest}"
    assert peak["fig13"] < 2.5, f"damped least squares peaked at {peak['fig13']:.2f} rad/s"
    assert peak["fig12"] > 2 * peak["fig13"], f"IK {peak['fig12']:.2f} rad/s vs DLS {peak['fig13']:.2f} rad/s"
    fig13 = logs["fig13"]
    following = np.linalg.norm(fig13["x_m"][:, :3] - fig13["x_d"][:, :3], axis=1)
    assert following.max() < 0.04, f"damped least squares fell {following.max() * 100:.1f} cm behind the target"
    fig12 = logs["fig12"]
    assert np.linalg.norm(fig12["x_m"][:, :3] - fig12["x_d"][:, :3], axis=1).max() < 0.005  # exact IK: within 5 mm


def test_switching_between_figures_12_and_13_while_servoing_completes(tmp_path):
    config = config_copy(CONFIGS / "visual_servoing.yaml", tmp_path, "lib_fig12_13")
    report = run_sim(config, tmp_path, "--alternate", "fig12,fig13", "--switches", "4", "--interval", "1")
    assert [s["to"] for s in report["switches"]] == ["fig13", "fig12", "fig13", "fig12"]
    assert report["states_at_stop"]["ik12"] == "ON" and report["states_at_stop"]["dls13"] == "OFF"
    assert_nothing_left(report)
