"""The end-of-run summary `pbo run` prints: reports/run_summary.py's, with the supervisor's lines
of restarts and decisions (reports/ does not import the supervisor)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rich.console import Console

    from pbo_runtime.config.model import Subsystem
    from pbo_runtime.reports.run_result import RunResult


def _print_summary(console: Console, subsystem: Subsystem, result: RunResult) -> None:
    from pbo_runtime.reports.run_summary import print_summary
    from pbo_runtime.supervisor.decisions import decision_lines
    from pbo_runtime.supervisor.restarts import restart_lines

    print_summary(console, subsystem, result, restart_lines([restart.to_json() for restart in result.restarts]),
                  decision_lines(result.decisions))
