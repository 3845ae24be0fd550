"""The trackball panel of the monitor in Debian's Chromium: the operator plays a trackball device
(configs/cartesian_teleop_hmi.yaml, `source: hmi`) with its sliders on a simulated-clock run, and the
desired pose the module writes moves by what was played."""

from __future__ import annotations

import json
import re
import subprocess

import pytest

from tests.support import PBO, REPO, start_hmi, start_run, stop_hmi, until

pytestmark = pytest.mark.multiprocess

expect = pytest.importorskip("playwright.sync_api").expect


def _x_d(subsystem: str) -> list[float]:
    shown = subprocess.run([*PBO, "svar", "x_d", "--subsystem", subsystem, "--format", "json"],
                           capture_output=True, text=True, timeout=60)
    row = next(r for r in json.loads(shown.stdout)["variables"] if r["name"] == "x_d")
    return [float(x) for x in re.findall(r"[-+]?\d+(?:\.\d*)?(?:e[-+]?\d+)?", row["value"])]  # its text, as shown


def test_the_operator_moves_the_hand_with_the_trackball_panels_sliders(page, tmp_path):
    subsystem = "hmi_ball"
    file = tmp_path / f"{subsystem}.yaml"
    file.write_text((REPO / "configs" / "cartesian_teleop_hmi.yaml").read_text()
                    .replace("subsystem: teleop_hmi", f"subsystem: {subsystem}"))
    run = start_run(file, tmp_path, "--clock", "sim", "--duration", "0")
    hmi, url = start_hmi(str(file), cwd=tmp_path)
    try:
        before = _x_d(subsystem)
        page.goto(url)
        panel = page.get_by_test_id("played-ball")
        expect(panel.get_by_label("ball dx (m)")).to_be_visible()
        panel.get_by_label("ball dx (m)").fill("0.05")
        expect(page.locator("[data-test=monitor-outcome]")).to_have_text("device 'ball' plays [0.05, 0, 0, 0, 0, 0]")
        until(lambda: abs(_x_d(subsystem)[0] - before[0] - 0.05) < 2e-3, "x_d moved 5 cm along x", safety_net=120)
        panel.get_by_role("button", name="Centre ball").click()
        expect(page.locator("[data-test=monitor-outcome]")).to_have_text("device 'ball' plays [0, 0, 0, 0, 0, 0]")
    finally:
        stop_hmi(hmi)
        run.send_signal(2)
        run.communicate(timeout=120)
