"""Both levels of the HMI in one session, as an engineer and then a user work in Debian's Chromium:
a job saved from the canvas joins the job dictionary at once, an application built from it with a
gap is refused a run, and once the gap is filled it runs on a `--clock sim` run started from the
file the HMI wrote, the header following its current job.
"""

from __future__ import annotations

import json
import subprocess

import pytest

from tests.support import PBO, WATCHED_SIM, start_hmi, start_run, stop_hmi, user_level_copy

pytestmark = pytest.mark.multiprocess

expect = pytest.importorskip("playwright.sync_api").expect


def test_a_job_saved_on_the_canvas_is_run_by_an_application_built_on_the_user_level(page, tmp_path):
    file = user_level_copy(tmp_path, "hmi_levels", reach_seconds=3.0)
    hmi, url = start_hmi(str(file), cwd=tmp_path)
    run = None
    try:
        page.goto(url)
        expect(page.locator("[data-test=no-run]")).to_be_visible()
        # the engineer: the PID loop, as the file has it, saved as a job of its own
        page.locator("[data-test=configuration-choice]").select_option("joint_pid")
        expect(page.locator("[data-test=checker]")).to_have_text("No error")
        job = page.get_by_role("form", name="save as job")
        job.get_by_label("Job name").fill("approach")
        job.get_by_label("Job name").press("Enter")
        expect(page.locator("[data-test=notice]")).to_contain_text(
            "saved job 'approach' (an action requiring an object of type joint_position)")

        # the user: the new job is in the dictionary without a reload
        page.get_by_role("tab", name="User: applications from jobs").click()
        dictionary = page.locator(".dictionary")
        expect(dictionary.locator("[data-icon=approach]")).to_be_visible()
        row = page.get_by_role("list", name="application workspace")
        for name in ("reach", "ready", "approach", "hold"):  # reach with its object, approach with a gap, hold
            dictionary.locator(f"[data-icon={name}]").focus()
            page.keyboard.press("Enter")
        gap = row.get_by_role("button", name="gap: an object of type joint_position for step 2 approach")
        expect(gap).to_be_visible()
        page.get_by_role("button", name="Run", exact=True).click()
        expect(page.locator("[data-test=workspace-message]")).to_contain_text(
            "Run refused: the application has 1 gap: step 2 'approach' needs an object of type joint_position")

        # the run starts from the file the HMI wrote; the page finds it by itself
        run = start_run(file, tmp_path, *WATCHED_SIM)
        expect(page.locator("[data-test=subsystem]")).to_have_text("hmi_levels")
        dictionary.locator("[data-icon=home]").drag_to(gap)
        expect(page.locator("[data-test=run-readiness]")).to_have_text("Complete: ready to run on the attached run.")
        page.get_by_role("button", name="Run", exact=True).click()
        expect(page.locator("[data-test=job]")).to_have_text("reach (application workspace)")
        expect(row.locator(".unit[data-step='1']")).to_have_attribute("aria-current", "step")
        # approach has no timeout: it puts its configuration on with its object and hands over at once
        expect(page.locator("[data-test=job]")).to_have_text("hold (application workspace)")
        expect(row.locator(".unit[data-step='3']")).to_have_attribute("aria-current", "step")
        goal = subprocess.run([*PBO, "svar", "q_d", "--subsystem", "hmi_levels", "--format", "json"], capture_output=True,
                              text=True, timeout=60)
        [q_d] = json.loads(goal.stdout)["variables"]
        assert (q_d["value"], q_d["sequence"]) == ("[" + ", ".join(["+0.0000"] * 6) + "]", 3), q_d  # initial, ready, home
    finally:
        stop_hmi(hmi)
        if run is not None:
            run.send_signal(2)
            run.communicate(timeout=120)
