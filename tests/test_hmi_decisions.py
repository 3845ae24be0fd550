"""The HMI's workspace builds steps that decide in Debian's Chromium: if, try, repeat and wait from the
dictionary, each with its rows filled by drag and drop and the keyboard, saved to the file (which then
checks clean) and run on a `--clock sim` run, the header and the workspace showing where it is.

With PBO_SCREENSHOTS naming a folder, the workspace with the four steps is saved there as hmi-workspace-decisions.png.
"""

from __future__ import annotations

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


def place(page, text: str):
    return page.get_by_role("button", name=text, exact=True)


def test_one_step_of_each_kind_is_built_from_the_dictionary_saved_and_run(page, tmp_path):
    # stuck fails at once (its pre-condition never holds); reach and hold run for their seconds of simulated time,
    # as many of wall time at least (WATCHED_SIM: --pace 1)
    file = user_level_copy(tmp_path, "hmi_decide", reach_seconds=3.0, hold_seconds=2.0)
    file.write_text(file.read_text().replace("  hold:  {configuration: joint_pid,",
                                             "  stuck: {configuration: joint_pid, object: none, pre: \"max(abs(q_m)) > 10\"}\n"
                                             "  hold:  {configuration: joint_pid,"))
    run = start_run(file, tmp_path, *WATCHED_SIM)
    hmi, url = start_hmi(str(file), cwd=tmp_path)
    try:
        open_user_level(page, url)
        expect(page.locator("[data-test=decisions] [data-icon]")).to_have_count(4)
        # try: [stuck], fallback: [reach: ready]
        icon(page, "try").drag_to(place(page, "insert the first step here"))
        expect(row(page).locator(".unit.decision[data-kind=try]")).to_be_visible()
        icon(page, "stuck").drag_to(place(page, "insert the first step here in try of step 1 try"))
        icon(page, "reach").drag_to(place(page, "insert the first step here in fallback of step 1 try"))
        expect(message(page)).to_contain_text("a gap opened")
        gap = row(page).get_by_role("button", name="gap: an object of type joint_position for step 1 reach")
        icon(page, "ready").drag_to(gap)
        # repeat: [hold] twice, by the keyboard: Enter appends the focused icon, Space selects, Enter on a place puts it
        icon(page, "repeat").focus()
        page.keyboard.press("Enter")
        icon(page, "hold").focus()
        page.keyboard.press("Space")
        place(page, "insert the first step here in repeat of step 2 repeat").focus()
        page.keyboard.press("Enter")
        page.get_by_label("times of step 2 repeat").fill("2")
        page.get_by_label("times of step 2 repeat").press("Tab")
        # wait, then if with hold in its then row
        icon(page, "wait").focus()
        page.keyboard.press("Enter")
        page.get_by_label("condition of step 3 wait").fill("max(abs(qd_m)) < 1")
        page.get_by_label("condition of step 3 wait").press("Tab")
        icon(page, "if").drag_to(place(page, "insert at the end of the row"))
        page.get_by_label("condition of step 4 if").fill("q_m[0] > 0.1")
        page.get_by_label("condition of step 4 if").press("Tab")
        icon(page, "hold").drag_to(place(page, "insert the first step here in then of step 4 if"))
        expect(row(page).locator(".unit.decision")).to_have_count(4)
        expect(page.locator("[data-test=run-readiness]")).to_have_text("Complete: ready to run on the attached run.")
        screenshot(page, "hmi-workspace-decisions.png")

        page.get_by_role("button", name="Save application").click()
        expect(message(page)).to_contain_text("application 'workspace' saved to")
        text = file.read_text()
        assert "try:" in text and "fallback:" in text and "repeat:" in text and "wait:" in text and "if:" in text
        check_clean(file)
        page.get_by_role("button", name="Clear the row").click()
        page.get_by_role("button", name="open application workspace in the workspace").click()
        expect(message(page)).to_have_text(
            "application 'workspace' opened in the workspace: Save with replace ticked writes it back")
        expect(row(page).locator(".unit.decision")).to_have_count(4)
        expect(row(page).locator(".decision[data-kind=try] [data-object=ready]")).to_be_visible()
        expect(page.get_by_label("condition of step 4 if")).to_have_value("q_m[0] > 0.1")

        page.get_by_role("button", name="Run", exact=True).click()
        expect(message(page)).to_have_text(
            "application 'workspace' runs its steps, deciding as it goes; pbo status shows where it is")
        expect(page.locator("[data-test=job]")).to_have_text("reach (workspace > fallback > reach)")
        fallback_reach = row(page).locator(".decision[data-kind=try] .unit[data-name=reach]")
        expect(fallback_reach).to_have_attribute("aria-current", "step")
        expect(page.locator("[data-test=job]")).to_contain_text("workspace > repeat")
        expect(page.locator("[data-test=job]")).to_have_text("hold (workspace > then > hold)")
        expect(page.locator("[data-test=workspace-running]")).to_have_text("No application is running.")
    finally:
        stop_hmi(hmi)
        run.send_signal(2)
        said, _ = run.communicate(timeout=120)
    assert "try failed -> fallback: job 'stuck' (workspace > try): pre-condition" in said
    assert "if q_m[0] > 0.1: then" in said


def test_of_two_identical_rows_only_the_running_one_is_lit(page, tmp_path):
    file = user_level_copy(tmp_path, "hmi_twins", hold_seconds=3.0)
    file.write_text(file.read_text() + "\napplications:\n  twins:\n"
                    + "".join('    - if: "q_m[0] > -10"\n      then: [hold]\n' for _ in range(2)))
    run = start_run(file, tmp_path, *WATCHED_SIM)
    hmi, url = start_hmi(str(file), cwd=tmp_path)
    try:
        open_user_level(page, url)
        page.get_by_role("button", name="open application twins in the workspace").click()
        expect(row(page).locator(".unit.decision")).to_have_count(2)
        first, second = (row(page).locator(f".decision[data-step='{n}'] .unit[data-name=hold]") for n in (1, 2))
        page.get_by_role("button", name="Run", exact=True).click()
        expect(first).to_have_attribute("aria-current", "step")  # the status path, 'twins > then > hold', fits both
        expect(second).not_to_have_attribute("aria-current", "step")
        expect(second).to_have_attribute("aria-current", "step")
        expect(first).not_to_have_attribute("aria-current", "step")
        expect(page.locator("[data-test=workspace-running]")).to_have_text("No application is running.")
    finally:
        stop_hmi(hmi)
        run.send_signal(2)
        run.communicate(timeout=120)
