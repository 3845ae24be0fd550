"""What the HMI's page, open and plotting, costs the RTPUs: jitter and overruns of the running demo
with and without it, in the same benchmark run.

As bench/api_stream.py (whose runs, rounds and tables this reuses), with the client a real page:
the browser HMI in Debian's Chromium, its monitor plotting 10 variables at 100 Hz (with the status
stream, the bus table and the arm drawing a page open on a run also has). The browser is started
once; during the runs without a page it is open with no page.

    python -m bench.hmi_load [--seconds 120] [--rounds 12]
"""

from __future__ import annotations

import argparse
import subprocess
import tempfile
from pathlib import Path
from typing import Any

from bench import api_stream
from bench._browser import Browser
from bench._common import Section

RATE = 100.0


class PageClient:
    """The monitor's page plotting element 0 of each of the 10 variables at 100 Hz while the run lasts."""

    def __init__(self, browser: Browser, url: str) -> None:
        self.browser = browser
        self.url = url
        self.messages = 0
        self.problem = ""
        self._page: Any = None

    def __enter__(self) -> PageClient:
        try:
            specs = [{"a": name, "b": None, "index": 0} for name in api_stream.VARIABLES]
            self._page = self.browser.open_monitor(self.url, specs, RATE, wait=False)
        except Exception as exc:  # reported in the section
            self.problem = f"{type(exc).__name__}: {str(exc).splitlines()[0]}"
        return self

    def __exit__(self, *_exc: object) -> None:
        if self._page is None:
            return
        try:
            self.messages = int(self._page.evaluate("() => (window.pboMonitor.plot || {samples: 0}).samples"))
        except Exception as exc:
            self.problem = f"{type(exc).__name__}: {str(exc).splitlines()[0]}"
        self._page.close()


def run(seconds: float = 120.0, rounds: int = 12) -> Section:
    per_run = seconds / rounds
    section = Section(
        key="hmi_load",
        title="The browser HMI: the monitor open and plotting 10 variables at 100 Hz, against no page",
        command=f"python -m bench.hmi_load --seconds {seconds:g} --rounds {rounds}",
        method=f"""
The demo (`configs/pid_joint.yaml` as subsystem `{api_stream.SUBSYSTEM}`, plus a tenth variable) runs on
the real clock in {rounds} rounds of two `pbo run`s of {per_run:g} s each: one with no page, one with the
HMI's page open in headless Chromium, its monitor plotting element 0 of each of the 10 variables at
{RATE:g} Hz (uPlot, redrawn once per animation frame) and showing what a page open on a run shows (the
tasks from the status stream at 2 Hz, the bus table every 2 s, the arm at 20 Hz). One `pbo hmi` and one
browser serve the whole benchmark; the side that runs first alternates. Per RTPU, from each run's
report: the release jitter p50 (median of its tasks) and p99 (its worst task), and its overruns. Ratios
are with / without the page: jitter as the median of the rounds' ratios, overruns pooled; the target is
at most {api_stream.LIMIT:g}x.
""",
        limits="""The browser (its renderer, GPU-less compositing), the server and the RTPUs share the machine's
2 vCPUs: what the page costs is their CPU time, which a SCHED_FIFO RTPU preempts. The same caveats as
for the API stream apply: tails and overruns on a shared VM vary with the hypervisor and with what else
runs; read the medians over the rounds, and rerun on a quiet machine before judging a few percent.""",
    )
    try:
        with tempfile.TemporaryDirectory(prefix="bench-hmi-") as name:
            folder = Path(name)
            file = api_stream.demo_copy(folder)
            browser = Browser()
            server, url = api_stream.start_server(folder)
            try:
                browser.warm(url)
                results: list[dict[str, dict[str, Any]]] = []
                for index in range(rounds):
                    order = ("none", "client") if index % 2 == 0 else ("client", "none")
                    results.append({side: api_stream.one_run(file, folder, per_run, url if side == "client" else None,
                                                             lambda u: PageClient(browser, u))
                                    for side in order})
            finally:
                server.terminate()
                try:
                    server.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    server.kill()
                    server.wait()
                browser.close()
    except Exception as exc:  # a benchmark that cannot run says why in its section
        section.notes.append(f"not measured: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")
        return section
    api_stream._tables(section, results, per_run, who="the page plotting", what="page: 10 variables at 100 Hz",
                       received="the page's plot took {n} samples")
    return section


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=120.0, help="seconds of runs on each side, over all rounds")
    parser.add_argument("--rounds", type=int, default=12)
    args = parser.parse_args()
    print(run(args.seconds, args.rounds).text())


if __name__ == "__main__":
    main()
