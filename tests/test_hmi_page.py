"""The browser HMI's frame, in Debian's Chromium: served by `pbo hmi`, loaded from the printed URL,
working with no run attached and showing a run once one is.
"""

from __future__ import annotations

import json
import subprocess

import pytest

from tests.support import PBO, demo_copy, start_hmi, start_run, stop_hmi

pytestmark = pytest.mark.multiprocess

expect = pytest.importorskip("playwright.sync_api").expect


def installed_modules() -> list[str]:
    listed = subprocess.run([*PBO, "lexicon", "--format", "json"], capture_output=True, text=True, timeout=60, check=True)
    return [module["name"] for module in json.loads(listed.stdout)]


NOT_RUNNING = ("--subsystem", "hmi_page_runs_nothing")  # whatever else runs on the machine, this page has no run


def test_the_printed_url_opens_the_hmi_which_forgets_the_token_and_lists_the_lexicon_with_no_run(page, tmp_path):
    hmi, url = start_hmi(*NOT_RUNNING, cwd=tmp_path)
    try:
        page.goto(url)
        expect(page.locator("[data-test=no-run]")).to_contain_text("No run attached")
        assert "token" not in page.url  # the cookie holds it now; the address bar and its history do not
        blocks = page.locator(".lexicon [data-module]")
        expect(blocks.first).to_be_visible()
        assert blocks.evaluate_all("blocks => blocks.map(b => b.dataset.module)") == installed_modules()
    finally:
        stop_hmi(hmi)


def test_the_working_levels_are_tabs_a_keyboard_can_switch(page, tmp_path):
    hmi, url = start_hmi(*NOT_RUNNING, cwd=tmp_path)
    try:
        page.goto(url)
        page.locator("#tab-engineer").focus()
        page.keyboard.press("Tab")
        page.keyboard.press("Enter")
        expect(page.locator("#tab-user")).to_have_attribute("aria-selected", "true")
        expect(page.locator("#pane-user")).to_be_visible()
        expect(page.locator("#pane-engineer")).to_be_hidden()
    finally:
        stop_hmi(hmi)


def test_attached_to_a_run_the_header_names_it_and_the_monitor_lists_its_tasks_by_rtpu(page, tmp_path):
    file = demo_copy(tmp_path, "hmi_frame")
    run = start_run(file, tmp_path, "--clock", "sim", "--duration", "0")
    hmi, url = start_hmi(str(file), cwd=tmp_path)
    try:
        page.goto(url)
        expect(page.locator("[data-test=subsystem]")).to_have_text("hmi_frame")
        expect(page.locator("[data-test=configuration]")).to_have_text("joint_pid")
        expect(page.locator("[data-test=illegal]")).to_have_text("Configuration legal")
        for rtpu, task in (("rtpu0", "traj"), ("rtpu0", "pid"), ("rtpu1", "robot")):
            expect(page.get_by_role("table", name=f"tasks on {rtpu}").locator(f"tr[data-task={task}] .state")).to_have_text("ON")
    finally:
        stop_hmi(hmi)
        run.send_signal(2)
        run.communicate(timeout=60)
