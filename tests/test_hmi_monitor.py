"""The monitor drawer in Debian's Chromium, on simulated-clock runs: tasks by RTPU, an ERROR task
cleared and turned on with its buttons while the illegal flag shows, the bus load predicted beside
measured, a configuration switch, a gain changed live and the tracking error it changes on the plot,
and the arm drawn from its joint frames. The plot's data is read from the page (window.pboMonitor),
never its pixels. With PBO_SCREENSHOTS=FOLDER, the kp test saves the monitor as hmi-monitor.png.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.support import REPO, demo_copy, screenshot, start_hmi, start_run, stop_hmi

pytestmark = pytest.mark.multiprocess

expect = pytest.importorskip("playwright.sync_api").expect

NET = 60_000  # ms: a net for a plot that never shows what is awaited (as expect's, set in conftest), never a timing

# The largest tracking error the plot holds now, over its series, and whether it has been steady
# over the last 20 samples (the arm at rest): read from the data the plot draws.
ERROR_NOW = """() => {
  const plot = window.pboMonitor && window.pboMonitor.plot;
  if (!plot || plot.data[0].length < 25) return null;
  const series = plot.data.slice(1);
  const last = series.map((s) => s.slice(-20));
  const spread = Math.max(...last.map((s) => Math.max(...s) - Math.min(...s)));
  return {now: Math.max(...series.map((s) => Math.abs(s[s.length - 1]))), spread};
}"""


def renamed_copy(name: str, folder: Path, subsystem: str) -> Path:
    """configs/NAME as subsystem `subsystem` (runs side by side never share a name), written to `folder`."""
    text = (REPO / "configs" / name).read_text()
    line = re.search(r"^subsystem: .*$", text, re.MULTILINE)
    assert line, f"configs/{name} has no subsystem line"
    path = folder / f"{subsystem}.yaml"
    path.write_text(text.replace(line.group(0), f"subsystem: {subsystem}", 1))
    return path


def stop(run) -> None:
    run.send_signal(2)
    run.communicate(timeout=60)


def task_row(page, rtpu: str, task: str):
    return page.get_by_role("table", name=f"tasks on {rtpu}").locator(f"tr[data-task={task}]")


def test_an_error_task_is_cleared_and_turned_on_with_its_buttons_while_the_flag_and_the_bus_show(page, tmp_path):
    file = renamed_copy("fault_drill.yaml", tmp_path, "hmi_monitor_drill")
    run = start_run(file, tmp_path, "--clock", "sim", "--duration", "0")
    hmi, url = start_hmi(str(file), cwd=tmp_path)
    try:
        page.goto(url)
        glitch = task_row(page, "rtpu0", "glitch")
        for rtpu, task in (("rtpu1", "robot"), ("rtpu0", "traj"), ("rtpu0", "pid")):
            expect(task_row(page, rtpu, task).locator(".state")).to_have_text("ON")
        expect(glitch).to_have_attribute("data-state", "ERROR")  # its cycle raised after 200 cycles
        expect(glitch.locator(".task-error")).to_contain_text("injected fault after 200 cycles")
        expect(page.locator("[data-test=illegal]")).to_have_text("Configuration illegal: critical tasks hold")
        expect(page.locator("[data-test=monitor-illegal]")).to_contain_text("In ERROR: glitch")
        bus = page.get_by_role("table", name="bus load")
        expect(bus.locator("tr[data-task=glitch] .measured")).to_have_text("0.0")  # ERROR: it moves nothing now
        expect(bus.locator("tr[data-task=glitch] .predicted")).not_to_have_text("0.0")

        expect(glitch.get_by_role("button", name="On glitch")).to_have_count(0)  # an ERROR is cleared first
        glitch.get_by_role("button", name="Clear glitch").click()
        expect(glitch).to_have_attribute("data-state", "OFF")
        glitch.get_by_role("button", name="On glitch").click()
        expect(glitch).to_have_attribute("data-state", "ON")
        expect(glitch.locator(".task-error")).to_have_text("")
        expect(page.locator("[data-test=illegal]")).to_have_text("Configuration legal")
        expect(page.locator("[data-test=monitor-illegal]")).to_have_count(0)
        expect(bus.locator("tr[data-task=glitch] .measured")).not_to_have_text("0.0")  # on again: measured from its rate
        expect(bus.locator("tr[data-task=B] .measured")).not_to_have_text("0.0")
    finally:
        page.close()  # before the server stops: the bus table's next request would find no server
        stop_hmi(hmi)
        stop(run)


def test_a_configuration_switch_turns_the_leaving_controller_off_and_the_entering_one_on(page, tmp_path):
    file = renamed_copy("switch_joint.yaml", tmp_path, "hmi_monitor_switch")
    run = start_run(file, tmp_path, "--clock", "sim", "--duration", "0")
    hmi, url = start_hmi(str(file), cwd=tmp_path)
    try:
        page.goto(url)
        expect(page.locator("[data-test=configuration]")).to_have_text("pid")
        switch = page.get_by_role("form", name="configuration switch")
        expect(switch.get_by_role("button", name="Switch")).to_be_disabled()  # the running one is chosen
        switch.get_by_label("configuration", exact=True).select_option("pd")
        switch.get_by_role("button", name="Switch").click()
        expect(page.locator("[data-test=monitor-outcome]")).to_contain_text("switched 'pid' -> 'pd'")
        expect(page.locator("[data-test=configuration]")).to_have_text("pd")
        expect(task_row(page, "rtpu0", "pd").locator(".state")).to_have_text("ON")
        expect(task_row(page, "rtpu0", "pid").locator(".state")).to_have_text("OFF")
        expect(page.get_by_role("table", name="bus load").locator("caption")).to_contain_text("'pd'")
    finally:
        page.close()  # before the server stops: the bus table's next request would find no server
        stop_hmi(hmi)
        stop(run)


def test_a_gain_changed_live_changes_the_plotted_tracking_error_and_the_arm_is_drawn(page, tmp_path):
    # Without gravity feed-forward nor integral, the arm at rest sags by g(q) / kp: a tenth of the gain, a larger error
    # (not ten times: the sagging arm leans out of the gravity that pulls it).
    file = demo_copy(tmp_path, "hmi_monitor_kp", pid={"params": {"kp": 400, "kd": 40, "ki": 0, "gravity_feedforward": False}})
    run = start_run(file, tmp_path, "--clock", "sim", "--duration", "0", live=True)
    hmi, url = start_hmi(str(file), cwd=tmp_path)
    try:
        page.goto(url)
        page.get_by_role("button", name="Plot tracking error q_r - q_m").click()
        expect(page.locator("[data-test=plot]")).to_have_attribute(
            "data-series", ";".join(f"q_r[{i}] - q_m[{i}]" for i in range(6)))
        expect(page.locator("[data-test=arm]")).to_have_attribute("data-frames", "7")  # six joints and the tool
        expect(page.get_by_role("img", name="arm, side (x, z)").locator("circle")).to_have_count(7)
        settled = f"() => {{ const e = ({ERROR_NOW})(); return e && e.spread < 1e-4 && e; }}"
        steady = page.wait_for_function(settled, timeout=NET).json_value()

        kp = page.get_by_label("pid kp", exact=True)
        expect(kp).to_have_value("400")
        kp.fill("fast")
        kp.press("Enter")  # the form is the keyboard's: Enter submits
        expect(page.locator("[data-test=monitor-outcome]")).to_contain_text("E308")  # checked as in the file: refused
        kp.fill("40")
        kp.press("Enter")
        expect(page.locator("[data-test=monitor-outcome]")).to_contain_text("'kp' of task 'pid' is 40")
        bigger = page.wait_for_function(f"() => {{ const e = ({ERROR_NOW})(); return e && e.now > {2 * steady['now']} && e; }}",
                                    timeout=NET)
        assert bigger.json_value()["now"] > 2 * steady["now"]
        page.locator("section.monitor").scroll_into_view_if_needed()
        screenshot(page, "hmi-monitor.png")
    finally:
        page.close()  # before the server stops: the bus table's next request would find no server
        stop_hmi(hmi)
        stop(run)
