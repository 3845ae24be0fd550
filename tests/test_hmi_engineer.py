"""The engineer level in Debian's Chromium (Onika §4.3): Figure 8 built by dragging lexicon blocks onto
an empty canvas, pins joined by variable name, the checker's badges, a second writer dimmed in the
lexicon, Save as job written to the file, and tasks spawned and turned off live on a `--clock sim` run.

Set PBO_SCREENSHOTS to a folder to keep a screenshot of the canvas with Figure 8 (hmi-canvas.png).
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

from tests.support import DEMO, PBO, canvas_base_file, live_demo_copy, screenshot, start_hmi, start_run, stop_hmi

pytestmark = pytest.mark.multiprocess

expect = pytest.importorskip("playwright.sync_api").expect

# Figure 8's modules, where each is dropped (x, y on the canvas)
FIGURE_8 = (("robot_torque", 130, 90), ("joint_trajectory", 130, 380), ("pid_joint", 430, 330), ("data_logger", 430, 80))
LOGGED = "[q_m, q_r, tau_u]"


def lexicon_block(page, module: str):
    return page.get_by_role("listbox", name="task lexicon").locator(f"[data-module={module}]")


def verdicts_current(page) -> None:
    """Wait until the lexicon's placement verdicts are those of the canvas as it is (the checker answered)."""
    expect(page.get_by_role("listbox", name="task lexicon")).to_have_attribute("aria-busy", "false")


def canvas_of(page):
    return page.get_by_role("application", name="job canvas")


def set_next_drop_modifier(page, module: str, modifier: str, value: str) -> None:
    """Select a lexicon block and give one of its modifiers a value for the next drop."""
    lexicon_block(page, module).click()
    page.get_by_role("form", name=f"modifiers of {module} for the next drop").get_by_label(f"modifier {modifier}").fill(value)


def drag_figure_8(page) -> None:
    canvas = canvas_of(page)
    set_next_drop_modifier(page, "data_logger", "variables", LOGGED)
    for module, x, y in FIGURE_8:
        block = lexicon_block(page, module)
        verdicts_current(page)
        expect(block).to_have_attribute("aria-disabled", "false")
        # grabbed by its top edge, beside the module's name: with 29 modules the block may sit at the
        # bottom of the scrolled lexicon, where its middle was not reliably under the pointer
        block.drag_to(canvas, source_position={"x": 30, "y": 12}, target_position={"x": x, "y": y})
        placed = canvas.locator(f"g.task[data-module={module}]")
        expect(placed).to_have_count(1)
        frame, box = canvas.bounding_box(), placed.bounding_box()
        drop = (frame["x"] + x, frame["y"] + y)  # rendered where the mouse button was let up
        assert box["x"] <= drop[0] <= box["x"] + box["width"], (module, box, drop)
        assert box["y"] <= drop[1] <= box["y"] + box["height"], (module, box, drop)


def drawn_links(page) -> set[str]:
    paths = canvas_of(page).locator("path.link")
    return set(paths.evaluate_all("ps => ps.map(p => `${p.dataset.variable}: ${p.dataset.from} -> ${p.dataset.to}`"
                                  " + (p.classList.contains('const') ? ' (const)' : ''))"))


def test_figure_8_dragged_onto_an_empty_canvas_joins_its_pins_by_variable_and_checks_clean(page, tmp_path):
    base = canvas_base_file(tmp_path, "canvas_fig8")
    hmi, url = start_hmi(str(base), cwd=tmp_path)
    try:
        page.goto(url)
        expect(canvas_of(page)).to_contain_text("Drag a module from the lexicon here")
        drag_figure_8(page)
        expect(page.locator("[data-test=checker]")).to_have_text("No error")
        links = drawn_links(page)
        for link in ("tau_u: pid_joint.tau -> robot_torque.tau_u", "q_m: robot_torque.q_m -> pid_joint.q_m",
                     "q_m: robot_torque.q_m -> joint_trajectory.q_m", "q_r: joint_trajectory.q_r -> pid_joint.q_r",
                     "qd_r: joint_trajectory.qd_r -> pid_joint.qd_r", "q_r: joint_trajectory.q_r -> data_logger.q_r",
                     "tau_u: pid_joint.tau -> data_logger.tau_u", "NDOF: robot_torque.ndof -> pid_joint.ndof (const)",
                     "ARM: robot_torque.arm_table -> pid_joint.arm_table (const)",
                     "EE: robot_torque.end_effector -> pid_joint.end_effector (const)"):
            assert link in links, (link, sorted(links))
        # q_d is the goal: no task writes it, job control does (its initial value), so its pin is not open
        expect(canvas_of(page).locator("g.task[data-module=joint_trajectory] .pin[data-port=q_d]")).to_have_class("pin")
        expect(canvas_of(page).locator(".badge")).to_have_count(0)
        page.mouse.move(640, 10)  # off the lexicon: no block's hover text in the picture
        screenshot(page, "hmi-canvas.png")
    finally:
        stop_hmi(hmi)


def test_with_figure_8_on_the_canvas_a_second_writer_of_tau_u_is_dimmed_with_the_reason_on_hover(page, tmp_path):
    hmi, url = start_hmi(str(canvas_base_file(tmp_path, "canvas_dim")), cwd=tmp_path)
    try:
        page.goto(url)
        second = lexicon_block(page, "inverse_dynamics")
        drag_figure_8(page)
        verdicts_current(page)
        expect(second).to_have_attribute("aria-disabled", "true")
        expect(second).to_have_attribute("title",
                                         "E401: variable 'tau_u' would have two writers on the canvas: 'pid_joint' and port "
                                         "'tau' of module 'inverse_dynamics' (an output has one writer; join them with "
                                         "a join connector (TR Figure 6))")
        expect(second).to_have_attribute("draggable", "false")
        second.hover()
        expect(second.locator(".lex-why")).to_be_visible()
        expect(second.locator(".lex-why")).to_contain_text("E401")
        second.focus()
        page.keyboard.press("Enter")  # unselectable: the keyboard places nothing either
        expect(lexicon_block(page, "gravity_compensation")).to_have_attribute("aria-disabled", "false")
        expect(canvas_of(page).locator("g.task")).to_have_count(4)
    finally:
        stop_hmi(hmi)


def two_writers_of_tau_u(folder: Path) -> Path:
    """The demo with a gravity compensation whose output is linked to tau_u too (the PID writes it)."""
    text = DEMO.read_text().replace("\nsubsystem: puma\n", "\nsubsystem: canvas_e401\n")
    text = text.replace("configurations:\n  joint_pid: [robot, traj, pid, logger]",
                        "  grav:   {module: gravity_compensation, rtpu: rtpu0, period: 1 ms, ports: {tau_g: tau_u}}\n\n"
                        "configurations:\n  joint_pid: [robot, traj, pid, logger, grav]")
    path = folder / "two_writers.yaml"
    path.write_text(text)
    return path


def test_two_writers_of_tau_u_loaded_from_a_file_show_e401_on_the_block_and_its_pin(page, tmp_path):
    hmi, url = start_hmi(str(two_writers_of_tau_u(tmp_path)), cwd=tmp_path)
    try:
        page.goto(url)
        grav = canvas_of(page).locator("g.task[data-task=grav]")
        expect(grav.locator(".block-badge")).to_have_attribute("data-code", "E401")
        expect(grav.locator(".block-badge")).to_contain_text("E401")
        expect(grav.locator(".pin-badge[data-port=tau_g]")).to_have_attribute(  # the message, its hint, then its notes
            "aria-label", re.compile(re.escape("E401: variable 'tau_u' has two writers in configuration 'joint_pid': 'pid' and "
                                               "'grav' (hint: an output has one writer; join them with a join connector "
                                               "(TR Figure 6))") + r"(\n  note: .+)+$"))
        expect(page.locator("[data-test=checker]")).to_have_text("1 error")
        # delete the second writer: the checker is clean again, and gravity compensation may be placed
        grav.click()
        page.get_by_role("button", name="Delete").click()
        expect(page.locator("[data-test=checker]")).to_have_text("No error")
        expect(lexicon_block(page, "gravity_compensation")).to_have_attribute("aria-disabled", "false")
    finally:
        stop_hmi(hmi)


def test_a_tasks_modifiers_are_checked_as_in_yaml_and_it_can_be_turned_off_and_replaced(page, tmp_path):
    demo = tmp_path / "pid_joint.yaml"
    demo.write_text(DEMO.read_text())
    hmi, url = start_hmi(str(demo), cwd=tmp_path)
    try:
        page.goto(url)
        canvas = canvas_of(page)
        pid = canvas.locator("g.task[data-task=pid]")
        expect(page.locator("[data-test=checker]")).to_have_text("No error")
        pid.click()
        panel = page.get_by_role("region", name="task pid")
        expect(panel.get_by_label("modifier kp")).to_have_value("400")
        panel.get_by_label("modifier kp").fill("\"stiff\"")
        panel.get_by_label("modifier kp").press("Enter")
        expect(pid.locator(".block-badge")).to_have_attribute("data-code", "E308")
        expect(page.locator(".diagnostics li[data-code=E308]")).to_contain_text("pid kp")
        panel.get_by_label("modifier kp").fill("300")
        panel.get_by_role("button", name="Apply").click()
        expect(page.locator("[data-test=checker]")).to_have_text("No error")
        # off: left out of the configuration, so nobody writes the robot's torque
        panel.get_by_role("button", name="Turn off").click()
        expect(pid).to_have_class(re.compile(r"\boff\b"))
        expect(canvas.locator("path.link[data-variable=tau_u]")).to_have_count(0)
        # (E408: the configuration leaves out the writer; the canvas shows it at the pin that misses it)
        expect(canvas.locator("g.task[data-task=robot] .pin-badge[data-port=tau_u]")).to_have_attribute("data-code", "E408")
        expect(page.locator(".diagnostics li[data-code=E408] .notes")).to_contain_text("note: pid task 'pid' writes 'tau_u'")
        panel.get_by_role("button", name="Turn on").click()
        expect(page.locator("[data-test=checker]")).to_have_text("No error")
        panel.get_by_label("replace by module").select_option("inverse_dynamics")
        panel.get_by_role("button", name="Replace").click()
        expect(canvas.locator("g.task[data-task=inverse_dynamics]")).to_have_count(1)
        expect(pid).to_have_count(0)
        badge = canvas.locator("g.task[data-task=inverse_dynamics] .pin-badge[data-port=qdd_r]")
        expect(badge).to_have_attribute("data-code", "E403")
    finally:
        stop_hmi(hmi)


def test_figure_8_placed_by_keyboard_is_saved_as_a_job_that_pbo_check_finds_clean(page, tmp_path):
    base = canvas_base_file(tmp_path, "canvas_save")
    hmi, url = start_hmi(str(base), cwd=tmp_path)
    try:
        page.goto(url)
        set_next_drop_modifier(page, "data_logger", "variables", LOGGED)
        for module, _, _ in FIGURE_8:
            verdicts_current(page)
            lexicon_block(page, module).focus()
            page.keyboard.press("Enter")  # placed at the next free spot
            expect(canvas_of(page).locator(f"g.task[data-module={module}]")).to_have_count(1)
        expect(page.locator("[data-test=checker]")).to_have_text("No error")
        job = page.get_by_role("form", name="save as job")
        job.get_by_label("Job name").fill("reach")
        job.get_by_label("Job name").press("Enter")
        expect(page.locator("[data-test=notice]")).to_contain_text(
            f"saved job 'reach' (an action requiring an object of type joint_position) to {base}: configuration 'reach'")
        # saved again under the same name: refused, with the API's one line, and the file kept
        job.get_by_role("button", name="Save as job").click()
        expect(page.get_by_role("alert")).to_contain_text(
            "save job reach: the file has a job 'reach' already: choose another name")
    finally:
        stop_hmi(hmi)
    checked = subprocess.run([*PBO, "check", str(base)], capture_output=True, text=True, timeout=60)
    assert checked.returncode == 0, checked.stdout + checked.stderr
    assert "actions requiring an object: reach (joint_position)" in checked.stdout
    assert "# the canvas's jobs go here" in base.read_text()


def test_attached_to_a_sim_run_a_dropped_task_is_spawned_and_its_toggle_turns_it_off_live(page, tmp_path):
    file = live_demo_copy(tmp_path, "canvas_live")
    run = start_run(file, tmp_path, "--clock", "sim", "--duration", "0")
    hmi, url = start_hmi(str(file), cwd=tmp_path)
    try:
        page.goto(url)
        canvas = canvas_of(page)
        expect(page.locator("[data-test=live]")).to_contain_text("canvas_live")
        expect(canvas.locator("g.task[data-task=pid] [data-test=state]")).to_have_text("ON")
        # dropped without what it logs: the run refuses the spawn, and the page says why in the API's words
        lexicon_block(page, "data_logger").drag_to(canvas, target_position={"x": 500, "y": 480})
        expect(page.get_by_role("alert")).to_contain_text("spawn data_logger: spawning task 'data_logger' would break the live "
                                                          "configuration:")
        expect(canvas.locator("g.task[data-module=data_logger]")).to_have_count(0)
        set_next_drop_modifier(page, "data_logger", "variables", LOGGED)
        lexicon_block(page, "data_logger").drag_to(canvas, target_position={"x": 500, "y": 480})
        logger = canvas.locator("g.task[data-task=data_logger]")
        expect(logger.locator("[data-test=state]")).to_have_text("ON")
        expect(page.locator("[data-test=notice]")).to_contain_text("spawn 'data_logger': done at the cycle boundary")
        panel = page.get_by_role("region", name="task data_logger")
        panel.get_by_role("button", name="Turn off").click()
        expect(logger.locator("[data-test=state]")).to_have_text("OFF")
        expect(panel.get_by_role("button", name="Turn on")).to_be_visible()
    finally:
        stop_hmi(hmi)
        run.send_signal(2)
        run.communicate(timeout=60)
