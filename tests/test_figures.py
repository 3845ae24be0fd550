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
