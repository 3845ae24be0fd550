"""The HMI's page in a real browser for the benchmarks: Debian's Chromium driven by Playwright, as the tests drive it.

`Browser()` launches one headless Chromium for a whole benchmark ($PBO_CHROMIUM, or chromium on
PATH; Playwright's own download is not used); `open_monitor(url, specs, rate)` opens the page from
`pbo hmi`'s printed URL and plots `specs` (the monitor's series: {"a": variable, "b": None, "index": i})
at `rate` Hz (window.pboMonitor.pending, set before the page's scripts run), waiting until the plot holds samples.
"""

from __future__ import annotations

import json
import os
import shutil
from typing import Any

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")
FLAGS = ["--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--disable-default-apps"]
READY_TIMEOUT_MS = 60_000  # a net for a page that never plots, never a timing


def chromium() -> str:
    """The Chromium to drive; RuntimeError saying how to get one."""
    found = os.environ.get("PBO_CHROMIUM") or next((p for name in CHROMIUM_NAMES if (p := shutil.which(name))), None)
    if not found:
        raise RuntimeError("no chromium on PATH (apt-get install chromium, or set PBO_CHROMIUM)")
    return found


class Browser:
    """One headless Chromium for a benchmark; `close()` ends it."""

    def __init__(self) -> None:
        from playwright.sync_api import sync_playwright

        self._playwright = sync_playwright().start()
        try:
            flags = FLAGS + (["--no-sandbox"] if os.geteuid() == 0 else [])
            self._browser = self._playwright.chromium.launch(executable_path=chromium(), headless=True, args=flags)
        except Exception:
            self._playwright.stop()
            raise

    def open_monitor(self, url: str, specs: list[dict[str, Any]], rate: float, wait: bool = True) -> Any:
        """A page 1280 px wide on `url`, its monitor plotting `specs` at `rate` Hz from its first render (the page;
        close it when done). `wait`: return once the plot holds samples (else as soon as the page has loaded)."""
        page = self._browser.new_page(viewport={"width": 1280, "height": 900})
        # before the page's own scripts: the plot starts with these series (window.pboMonitor.pending)
        page.add_init_script(script=f"window.pboMonitor = {{pending: {json.dumps({'specs': specs, 'rate': rate})}}};")
        page.goto(url)
        if wait:
            page.wait_for_function("() => window.pboMonitor.plot && window.pboMonitor.plot.samples > 0", timeout=READY_TIMEOUT_MS)
        return page

    def warm(self, url: str) -> None:
        """Load the page once and close it: the server's first answers (the lexicon imports every module) are not a run's."""
        page = self._browser.new_page(viewport={"width": 1280, "height": 900})
        try:
            page.goto(url)
            page.wait_for_selector(".lexicon [data-module]", timeout=READY_TIMEOUT_MS)
        finally:
            page.close()

    def close(self) -> None:
        try:
            self._browser.close()
        finally:
            self._playwright.stop()
