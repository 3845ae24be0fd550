"""The HMI's user level in Debian's Chromium (Onika §4.4): the job dictionary's interlocking icons, the
application workspace (drag and drop and keyboard, gaps, refusals with their reason), object values
edited and saved to the file, an incomplete application saved and reused as an icon, and Run on a
`--clock sim` run showing the current job in the workspace and the header.

With PBO_SCREENSHOTS naming a folder, the workspace with a gap is saved there as hmi-workspace-gap.png.
"""

from __future__ import annotations

import re

import pytest

from tests.support import (
    WATCHED_SIM,
    check_clean,
    icon,
    message,
    open_user_level,
    row,
    screenshot,
    start_hmi,
    start_run,
    stop_hmi,
    user_level_copy,
)

pytestmark = pytest.mark.multiprocess

expect = pytest.importorskip("playwright.sync_api").expect

GAP_REFUSED = ("Run refused: the application has 1 gap: step 1 'reach' needs an object of type joint_position; "
               "drop an object of that type on each gap")


def test_an_application_with_a_gap_is_refused_a_run_until_filled_then_runs_showing_the_current_job(page, tmp_path):
    file = user_level_copy(tmp_path, "hmi_user_run", reach_seconds=3.0)
    run = start_run(file, tmp_path, *WATCHED_SIM)
    hmi, url = start_hmi(str(file), cwd=tmp_path)
    try:
        open_user_level(page, url)
        icon(page, "reach").drag_to(row(page).get_by_role("button", name="insert the first step here"))
        gap = row(page).get_by_role("button", name="gap: an object of type joint_position for step 1 reach")
        expect(gap).to_be_visible()
        expect(message(page)).to_contain_text("a gap opened")
        icon(page, "hold").focus()
        page.keyboard.press("Enter")  # the keyboard's way: Enter appends the focused icon
        expect(row(page).locator(".unit")).to_have_count(2)
        expect(page.locator("[data-test=run-readiness]")).to_have_text(
            "Not runnable: 1 gap to fill (it can be saved as an incomplete application).")
        screenshot(page, "hmi-workspace-gap.png")

        page.get_by_role("button", name="Run", exact=True).click()
        expect(message(page)).to_have_text(GAP_REFUSED)
        expect(page.locator("[data-test=job]")).to_have_text("none")  # nothing ran

        icon(page, "ready").drag_to(gap)
        expect(gap).to_have_count(0)
        expect(row(page).locator(".unit[data-step='1'] [data-object=ready]")).to_be_visible()
        expect(page.locator("[data-test=run-readiness]")).to_have_text("Complete: ready to run on the attached run.")

        page.get_by_role("button", name="Run", exact=True).click()
        expect(message(page)).to_have_text(
            "application 'workspace' runs its jobs (reach, hold); pbo status shows the current one")
        expect(page.locator("[data-test=job]")).to_have_text("reach (application workspace)")
        expect(row(page).locator(".unit[data-step='1']")).to_have_attribute("aria-current", "step")
        expect(page.locator("[data-test=running-job]")).to_have_text("reach")
        expect(page.locator("[data-test=job]")).to_have_text("hold (application workspace)")
        expect(row(page).locator(".unit[data-step='2']")).to_have_attribute("aria-current", "step")
        expect(row(page).locator(".unit[data-step='1']")).not_to_have_attribute("aria-current", "step")
    finally:
        stop_hmi(hmi)
        run.send_signal(2)
        run.communicate(timeout=120)


def test_icons_that_do_not_interlock_are_refused_with_the_reason_and_edges_match_by_type(page, tmp_path):
    file = user_level_copy(tmp_path, "hmi_user_refuse")
    hmi, url = start_hmi(str(file), cwd=tmp_path)
    try:
        open_user_level(page, url)
        notch = icon(page, "reach").locator(".edge-right").get_attribute("stroke")
        assert notch and notch == icon(page, "ready").locator(".edge-left").get_attribute("stroke")
        assert icon(page, "hold").locator(".icon-edge").count() == 0  # an action: both edges flat
        expect(page.get_by_role("button", name="reach: job, an action requiring an object of type joint_position",
                                exact=True)).to_be_visible()

        icon(page, "hold").focus()
        page.keyboard.press("Enter")
        icon(page, "ready").focus()
        page.keyboard.press("Enter")  # an object after an action: its tab meets a flat edge
        expect(message(page)).to_have_text("Refused: object 'ready' (type joint_position) does not interlock with 'hold', "
                                           "an action (its right edge is flat)")
        expect(row(page).locator(".unit")).to_have_count(1)

        icon(page, "reach").drag_to(row(page).get_by_role("button", name="insert before step 1"))
        gap = row(page).get_by_role("button", name=re.compile("^gap: an object of type joint_position"))
        icon(page, "hold").drag_to(gap)  # an action into an object's slot
        expect(message(page)).to_have_text("Refused: the slot of step 1 takes an object of type joint_position; 'hold' is "
                                           "an action, not an object: drop it between steps")
        expect(row(page).locator(".unit")).to_have_count(2)

        # remove and reorder: the selected icon goes where Enter is pressed; Alt+arrows move a step
        row(page).locator(".unit[data-step='2'] .step-icon").focus()
        page.keyboard.press("Alt+ArrowLeft")
        expect(row(page).locator(".unit[data-step='1']")).to_have_attribute("data-name", "hold")
        row(page).get_by_role("button", name="remove step 2 reach").click()
        expect(row(page).locator(".unit")).to_have_count(1)
    finally:
        stop_hmi(hmi)


def test_an_objects_value_edited_in_the_dictionary_and_in_the_workspace_is_saved_to_the_file(page, tmp_path):
    file = user_level_copy(tmp_path, "hmi_user_object")
    hmi, url = start_hmi(str(file), cwd=tmp_path)
    try:
        open_user_level(page, url)
        page.get_by_role("button", name="edit the values of ready").click()
        editor = page.get_by_role("form", name="values of object ready")
        field = editor.get_by_label("ready[0]")
        expect(field).to_have_value("0.3")
        field.fill("0.7")
        field.press("Enter")
        expect(editor.locator("[data-test=object-message]")).to_have_text(f"object 'ready' saved to {file}")
        saved = "ready: {type: joint_position, value: [0.7, -0.5, 0.5, 0.2, 0.4, 0.2], doc: \"upper arm raised\"}"
        assert saved in file.read_text()
        assert "  joint_pid: [robot, traj, pid]  # the PID loop\n" in file.read_text()  # comments kept
        check_clean(file)

        # in the workspace: the object that fills a slot opens the same editor there
        icon(page, "reach").focus()
        page.keyboard.press("Enter")
        icon(page, "home").drag_to(row(page).get_by_role("button", name=re.compile("^gap: an object of type joint_position")))
        row(page).locator("[data-object=home]").click()
        editor = page.locator("[data-test=object-editor-workspace]")
        expect(editor).to_be_visible()
        field = editor.get_by_label("home[5]")
        field.fill("")
        editor.get_by_role("button", name="Save values to the file").click()
        expect(editor.locator("[data-test=object-message]")).to_contain_text("Not saved")
        field.fill("-0.25")
        editor.get_by_role("button", name="Save values to the file").click()
        expect(editor.locator("[data-test=object-message]")).to_have_text(f"object 'home' saved to {file}")
        assert re.search(r"\n  home: +\{type: joint_position, value: \[0.0, 0.0, 0.0, 0.0, 0.0, -0.25\]\}\n", file.read_text())
        check_clean(file)
    finally:
        stop_hmi(hmi)


def test_an_incomplete_application_is_saved_to_the_file_and_reused_as_an_icon(page, tmp_path):
    file = user_level_copy(tmp_path, "hmi_user_save")
    hmi, url = start_hmi(str(file), cwd=tmp_path)
    try:
        open_user_level(page, url)
        for name in ("reach", "hold"):
            icon(page, name).focus()
            page.keyboard.press("Enter")
        page.get_by_label("Application name", exact=True).fill("approach")
        page.get_by_role("button", name="Save application").click()
        expect(message(page)).to_contain_text(f"application 'approach' saved to {file}, incomplete (1 gap(s))")
        assert "applications:\n  approach:\n    - reach\n    - hold\n" in file.read_text()
        assert "W701" in check_clean(file)

        reused = page.get_by_role("button", name="approach: application, an action requiring an object of type joint_position",
                                   exact=True)
        expect(reused).to_be_visible()
        expect(page.locator("[data-test=actions-requiring-object] [data-icon=approach]")).to_be_visible()
        page.get_by_role("button", name="Clear the row").click()
        reused.drag_to(row(page).get_by_role("button", name="insert the first step here"))
        expect(row(page).get_by_role("button", name="gap: an object of type joint_position for step 1 approach")).to_be_visible()
        icon(page, "ready").drag_to(row(page).get_by_role("button", name=re.compile("^gap: an object")))
        page.get_by_label("Application name", exact=True).fill("tour")
        page.get_by_role("button", name="Save application").click()
        expect(message(page)).to_contain_text(f"application 'tour' saved to {file}, complete")
        assert "  tour:\n    - approach: ready\n" in file.read_text()
        check_clean(file)
        expect(page.locator("[data-test=actions] [data-icon=tour]")).to_be_visible()

        page.get_by_role("button", name="Save application").click()  # again: the name is taken
        expect(message(page)).to_have_text(f"Not saved: application 'tour' exists in {file}: choose another name, or replace it")

        page.get_by_role("button", name="open application approach in the workspace").click()  # back in the row, to change
        expect(row(page).locator(".unit")).to_have_count(2)
        gap = row(page).get_by_role("button", name=re.compile("^gap: an object of type joint_position for step 1 reach"))
        expect(gap).to_be_visible()
        expect(page.get_by_label("Application name", exact=True)).to_have_value("approach")
    finally:
        stop_hmi(hmi)


def test_run_with_no_run_attached_is_refused_saying_how_to_attach_one(page, tmp_path):
    file = user_level_copy(tmp_path, "hmi_user_norun")
    hmi, url = start_hmi(str(file), cwd=tmp_path)
    try:
        open_user_level(page, url)
        icon(page, "hold").focus()
        page.keyboard.press("Enter")
        page.get_by_role("button", name="Run", exact=True).click()
        expect(message(page)).to_have_text("Run refused: no run is attached: start one with pbo run FILE (the HMI attaches "
                                           "to it by itself)")
    finally:
        stop_hmi(hmi)
