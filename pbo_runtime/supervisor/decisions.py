"""Running an application whose steps decide (`if`, `try`, `repeat`, `wait`; config.decisions).

Job control takes each decision when the step is reached, on the values the table holds then:
between two of the host's pumps, which on the simulated clock is a tick boundary, so a run
replays its decisions bit for bit. Each decision, each failure that sent a `try` to its
fallback, each turn of a repeat is recorded with the values that made it (`JobControl.decisions`,
listed by the run's summary and report.json); `JobControl.path` is where the application is now
(`pick > try > approach`), which `pbo status` shows, and `JobControl.place` the same as positions
(step 2, row 1 (the fallback), step 0: `[2, 1, 0]`), which tells two identical rows apart.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from pbo_runtime.config.model import ApplicationStep, Decision
from pbo_runtime.reports.run_records import DecisionTaken, Numbers


def plain(values: Mapping[str, Any]) -> dict[str, Numbers]:
    """Variable values as JSON: lists of numbers."""
    return {name: np.asarray(value).tolist() for name, value in values.items()}


def decision_lines(decisions: Sequence[DecisionTaken]) -> list[str]:
    """The summary's lines: each decision, where it was taken, which way it went and on what values."""
    lines = []
    for entry in decisions:
        values = "; ".join(f"{name} = {np.round(np.asarray(value), 4).tolist()}"
                           for name, value in (entry.values or {}).items())
        what = {"if": f"if {entry.condition}: {entry.taken}",
                "try": f"try failed -> fallback: {entry.failure}",
                "repeat": f"repeat {entry.turn}/{entry.of}" + (f" until {entry.condition}: {entry.taken}"
                                                               if entry.condition is not None else ""),
                "wait": f"wait {entry.condition}: held after {entry.waited:.3f} s"}[entry.kind]
        shown = f" ({values})" if values and entry.kind != "try" else ""  # a failure's message has its values
        lines.append(f"decision at {entry.time:.3f} s ({entry.path}): {what}{shown}")
    return lines


class DecidingRun:
    """Walks an application's steps, taking the decisions; JobFailure out of it ends the application."""

    def __init__(self, control: Any, evaluate: Callable[[Any, str], tuple[bool, dict[str, Any]]],
                 failure: type[Exception], poll: float) -> None:
        """`control` is job control (`supervisor.job_control`, which imports this); `evaluate`, `failure` and
        `poll` are its: how a condition is read, what a failure is, how often."""
        self.control = control
        self.evaluate, self.failure, self.poll = evaluate, failure, poll
        self.host = control.host
        self.subsystem = control.subsystem

    def run(self, application: str, fill: Any = None) -> None:
        self.control.path.append(application)
        try:
            self.row(self.subsystem.applications[application].steps, fill, application)
        finally:
            self.control.path.pop()

    def row(self, steps: tuple[ApplicationStep, ...], fill: Any, application: str) -> None:
        place = self.control.place
        for index, step in enumerate(steps):
            place.append(index)
            try:
                self.step(step, fill, application)
            finally:
                place.pop()

    def step(self, step: ApplicationStep, fill: Any, application: str) -> None:
        given = self.subsystem.objects[step.object].value if step.object is not None else step.fill
        if given is None:
            given = fill
        if step.decision is not None:
            self.decide(step.decision, fill, application)
        elif step.is_application:
            self.run(step.job, given)
        else:
            arguments = dict(step.arguments)
            variable = self.subsystem.jobs[step.job].object
            if variable is not None and variable not in arguments and given is not None:
                arguments[variable] = given
            self.control.path.append(step.job)
            try:
                self.control.run_job(step.job, arguments, step=f" ({' > '.join(self.control.path[:-1])})")
            finally:
                self.control.path.pop()
            self.control.jobs_done.append(step.job)

    def fail(self, message: str, values: dict[str, Any]) -> Exception:
        return self.failure(message, values)

    def record(self, kind: str, taken: str = "", condition: str | None = None, values: Mapping[str, Numbers] | None = None,
               failure: str = "", turn: int = 0, of: int = 0, waited: float = 0.0) -> None:
        taken_at = DecisionTaken(self.host.now(), " > ".join(self.control.path), kind, taken, condition, values, failure,
                                 turn, of, waited)
        self.control.decisions.append(taken_at)
        self.control.mark(taken_at.time, "decision", f"{kind}: {taken}".rstrip(": "))

    def decide(self, decision: Decision, fill: Any, application: str) -> None:
        control, host, evaluate = self.control, self.host, self.evaluate
        if decision.kind == "if":
            assert decision.condition is not None
            holds, values = evaluate(host, decision.condition)
            taken = "then" if holds else "else"
            self.record("if", condition=decision.condition, values=plain(values), taken=taken)
            host.say(f"{' > '.join(control.path)}: if {decision.condition}: {taken}")
            self.nested(taken, decision.rows[0 if holds else 1], fill, application, 0 if holds else 1)
        elif decision.kind == "try":
            try:
                self.nested("try", decision.rows[0], fill, application)
            except self.failure as failure:
                self.record("try", taken="fallback", failure=str(failure), values=plain(getattr(failure, "values", {})))
                host.say(f"{' > '.join(control.path)}: try failed, fallback: {failure}")
                self.nested("fallback", decision.rows[1], fill, application, 1)
        elif decision.kind == "repeat":
            self.repeat(decision, fill, application)
        else:
            self.wait(decision)

    def nested(self, label: str, steps: tuple[ApplicationStep, ...], fill: Any, application: str, which: int = 0) -> None:
        """Row `which` of a step that decides (if: then 0, else 1; try: try 0, fallback 1; repeat: 0)."""
        self.control.path.append(label)
        self.control.place.append(which)
        try:
            self.row(steps, fill, application)
        finally:
            self.control.place.pop()
            self.control.path.pop()

    def repeat(self, decision: Decision, fill: Any, application: str) -> None:
        most = decision.times if decision.times is not None else decision.most or 1
        values: dict[str, Any] = {}
        for turn in range(1, most + 1):
            self.nested(f"repeat {turn}/{most}", decision.rows[0], fill, application)
            if decision.condition is None:
                self.record("repeat", turn=turn, of=most)
                continue
            holds, values = self.evaluate(self.host, decision.condition)
            self.record("repeat", turn=turn, of=most, condition=decision.condition, values=plain(values),
                        taken="done" if holds else ("again" if turn < most else "failed"))
            if holds:
                return
        if decision.condition is not None:
            raise self.fail(f"{' > '.join(self.control.path)}: repeat ran {most} times; '{decision.condition}' still false",
                            values)

    def wait(self, decision: Decision) -> None:
        host, condition = self.host, decision.condition
        assert condition is not None
        started = host.now()
        self.control.path.append("wait")
        try:
            while True:
                holds, values = self.evaluate(host, condition)
                if holds:
                    self.record("wait", condition=condition, values=plain(values), taken="holds",
                                waited=host.now() - started)
                    return
                if decision.timeout is not None and host.now() - started > decision.timeout:
                    raise self.fail(f"{' > '.join(self.control.path)}: '{condition}' still false after "
                                    f"{decision.timeout:g} s", values)
                host.pump(self.poll)
        finally:
            self.control.path.pop()
