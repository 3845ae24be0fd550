"""The HMI on an application file, in Debian's Chromium: its `run:` as parallel steps with one arm per
subsystem, a stage built from the dictionary (grouped by subsystem), saved (the file then checks clean)
and run on the simulated clock as `pbo run APP.yaml` runs it, each arm lighting its running step.

With PBO_SCREENSHOTS naming a folder, the workspace with the new stage is saved there as hmi-workspace-parallel.png,
and the run in its second stage as hmi-workspace-parallel-running.png.
"""

from __future__ import annotations

import pytest

from tests.support import REPO, check_clean, message, row, screenshot, start_hmi, stop_hmi

pytestmark = pytest.mark.multiprocess

expect = pytest.importorskip("playwright.sync_api").expect


def place(page, text: str):
    return page.get_by_role("button", name=text, exact=True)


def subsystem_icon(page, subsystem: str, name: str):
    return page.locator(f"[data-subsystem={subsystem}] [data-icon={name}]")


def arm(page, stage: int, subsystem: str):
    return row(page).locator(f".unit.parallel[data-step='{stage}'] [data-arm={subsystem}]")


def test_a_parallel_stage_is_built_from_the_dictionary_saved_and_run_arm_by_arm(page, tmp_path):
    file = tmp_path / "two_arms.yaml"
    # the shipped file, its left arm waving long enough on the simulated clock to be seen doing it
    file.write_text((REPO / "configs" / "two_arms.yaml").read_text().replace("times: 2", "times: 30", 1))
    hmi, url = start_hmi(str(file), cwd=tmp_path)
    try:
        page.goto(url)
        expect(row(page).locator(".unit.parallel")).to_have_count(3)  # the shipped file's three stages
        expect(arm(page, 2, "left").locator(".unit[data-name=wave]")).to_be_visible()
        expect(arm(page, 3, "left").locator(".decision[data-kind=if] .unit[data-name=reach]")).to_be_visible()

        # a fourth stage, both arms up again: the parallel icon dragged to the end, then each arm's reach with its object
        page.locator("[data-test=stages] [data-icon=parallel]").drag_to(place(page, "insert at the end of the row"))
        expect(row(page).locator(".unit.parallel")).to_have_count(4)
        subsystem_icon(page, "left", "reach").drag_to(place(page, "insert the first step here in left of step 4 parallel"))
        expect(message(page)).to_contain_text("a gap opened")
        subsystem_icon(page, "left", "ready").drag_to(
            arm(page, 4, "left").get_by_role("button", name="gap: an object of type joint_position for step 1 reach"))
        subsystem_icon(page, "right", "reach").focus()
        page.keyboard.press("Enter")  # appended to right's arm of the last stage
        right_gap = arm(page, 4, "right").get_by_role("button", name="gap: an object of type joint_position for step 1 reach")
        expect(message(page)).to_contain_text("'reach' inserted as step 1 in the arm right of step 4 (parallel)")
        # left's icons in right's arm are refused (a click selects an icon, a click on a gap or place puts it there)
        subsystem_icon(page, "left", "home").click()
        right_gap.click()
        expect(message(page)).to_contain_text("Refused: 'home' is an object of subsystem 'left'")
        subsystem_icon(page, "left", "reach").click()
        place(page, "insert at the end of the row in right of step 4 parallel").click()
        expect(message(page)).to_contain_text("Refused: 'reach' is a step of subsystem 'left'")
        subsystem_icon(page, "right", "ready").click()
        right_gap.click()
        expect(arm(page, 4, "right").locator("[data-object=ready]")).to_be_visible()
        expect(page.locator("[data-test=run-readiness]")).to_have_text("Changed: save the stages to run them.")
        page.locator(".dictionary-pane").evaluate("pane => { pane.scrollTop = 0; }")  # the picture shows the Stages section
        screenshot(page, "hmi-workspace-parallel.png")

        # a condition the left subsystem cannot read: every arm interlocks, but the file would not check
        condition = arm(page, 3, "left").get_by_label("condition of step 1 if")
        condition.fill("q_nowhere[0] > 0")
        before = file.read_text()
        page.get_by_role("button", name="Save stages").click()
        expect(message(page)).to_contain_text("Not saved: ")
        expect(message(page)).to_contain_text("two_arms.yaml would have 1 error, the first: ")
        expect(message(page)).to_contain_text("error[E813]: run: stage 3: the steps of subsystem 'left' do not interlock")
        assert file.read_text() == before
        condition.fill("abs(q_m[0]) > 0.01")
        page.get_by_role("button", name="Save stages").click()
        expect(message(page)).to_have_text("run: saved to two_arms.yaml, 4 stage(s); pbo check finds no error")
        text = file.read_text()
        assert "left: [reach: ready]\n      right: [reach: ready]\n" in text
        assert "# the left arm waves, the right one holds" in text  # the stages that did not change kept their lines
        check_clean(file)

        page.get_by_label("clock").select_option("sim")
        page.get_by_role("button", name="Run", exact=True).click()
        expect(message(page)).to_contain_text("pbo run two_arms.yaml --clock sim started")
        # the left arm waving (lengthened above: the page reads the status twice a second) is lit while it runs
        expect(arm(page, 2, "left").locator(".unit[data-name=wave]")).to_have_attribute("aria-current", "step")
        expect(page.locator("[data-test=subsystem-path-left]")).to_contain_text("(stage 2: wave > repeat")
        screenshot(page, "hmi-workspace-parallel-running.png")
        expect(page.locator("[data-test=workspace-running]")).to_contain_text(
            "Ended: every subsystem ran its stages to the end (exit 0)")
        # each arm is marked done from the run's own output, however short its stage was
        for stage, subsystem in ((1, "left"), (1, "right"), (2, "left"), (4, "left"), (4, "right")):
            expect(arm(page, stage, subsystem)).to_have_attribute("data-done", "true")
        expect(arm(page, 2, "right")).not_to_have_attribute("data-done", "true")  # no arm there: nothing it ran
    finally:
        stop_hmi(hmi)
