"""Steps that decide (`if`, `try`, `repeat`, `wait`): each row checked as a sequence, conditions against the shapes.

Every path must interlock as a sequence does (DESIGN §16): a row's steps are checked by the job
rules (`checker.jobs`), their gaps are the application's (a gap on any path makes it
incomplete), and a condition is evaluated once on zeros of its variables' declared shapes, so
an index out of range or shapes that do not broadcast are found before a run.
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from pbo_runtime.config.checker.base import CheckerBase
from pbo_runtime.config.checker.words import describe
from pbo_runtime.config.decisions import step_can_fail
from pbo_runtime.config.expressions import compile_condition
from pbo_runtime.config.model import DECISIONS, NOWHERE, ApplicationSpec, ApplicationStep, Decision, Gap, Location
from pbo_runtime.config.units import TIME
from pbo_runtime.config.yaml_nodes import YList, YMap, location_of

KEYS = {"if": ("if", "then", "else"), "try": ("try", "fallback"), "repeat": ("repeat", "times", "until", "max"),
        "wait": ("wait", "timeout")}
REQUIRED = {"if": ("then",), "try": ("fallback",), "repeat": (), "wait": ()}
ROWS = {"if": ("then", "else"), "try": ("try", "fallback"), "repeat": ("repeat",), "wait": ()}
EXAMPLES = {
    "if": '- if: "norm(q_m - q_d) < 0.05"\n  then: [settle: ready]\n  else: [reach: ready]',
    "try": "- try: [reach: far]\n  fallback: [reach: ready]",
    "repeat": "- repeat: [reach: ready, reach: home]\n  times: 3   (or until: \"CONDITION\" with max: N)",
    "wait": '- wait: "max(abs(qd_m)) < 0.01"\n  timeout: 2 s',
}


@dataclass(frozen=True)
class StepDraft:
    """A step as `check_step` left it: a job's step whole; an application's with what it was given, checked later."""

    step: ApplicationStep
    gap: str | None  # a job step without its object: the object type it needs
    given: Any = None  # an application step's object (a name, or {type: value}), as written
    given_loc: Location = NOWHERE
    rows: tuple[tuple[StepDraft, ...], ...] = ()  # a step that decides: its rows of steps (checker.decisions)


def decision_kind(item: Any) -> str | None:
    """The kind of a step that decides (its first key), or None for a job or an application step."""
    if isinstance(item, YMap) and item:
        first = next(iter(item))
        if first in DECISIONS:
            return str(first)
    return None


def used_applications(item: StepDraft) -> Iterator[str]:
    """The applications a step uses, inside the rows of the steps that decide too."""
    if item.step.is_application:
        yield item.step.job
    for row in item.rows:
        for inner in row:
            yield from used_applications(inner)


class DecisionChecks(CheckerBase):
    """Rules for the steps that decide."""

    if TYPE_CHECKING:  # rules of other mixins this one calls; the whole checker has them
        def check_step(self, app: str, number: int, item: Any, loc: Location) -> StepDraft | None: ...
        def check_expression(self, value: Any, loc: Location, what: str) -> str | None: ...
        def fill_application(self, app: str, number: int, inner: ApplicationSpec, item: StepDraft) -> ApplicationStep | None: ...

    def check_decision(self, app: str, number: int, item: YMap, kind: str) -> StepDraft | None:
        """A step that decides, as far as it can be checked before the applications it uses are."""
        where = f"the {kind} of step {number} of application '{app}'"
        ok = True
        missing = [key for key in REQUIRED[kind] if key not in item]
        for key in item:
            if key not in KEYS[kind]:
                close = difflib.get_close_matches(str(key), missing, n=1, cutoff=0.6)
                missing = [m for m in missing if m not in close]  # one mistake, one error
                self.error("E720", f"{where}: unknown key '{key}'" + (f": did you mean '{close[0]}'?" if close else ""),
                           item.key_loc(key), f"a {kind} step has: {', '.join(KEYS[kind])}; e.g.\n{EXAMPLES[kind]}")
                ok = False
        for key in missing:
            self.error("E720", f"{where} has no '{key}:'", item.key_loc(kind), f"e.g.\n{EXAMPLES[kind]}")
            ok = False
        rows: list[tuple[StepDraft, ...]] = []
        for key in ROWS[kind]:
            row = self.decision_row(app, number, item, key, where, kind) if key in item else ()
            ok = ok and row is not None
            rows.append(row or ())
        decision = Decision(kind)
        if kind in ("if", "wait") or "until" in item:
            key = "until" if kind == "repeat" else kind
            condition = self.decision_condition(item[key], item.value_loc(key), f"the condition of {where}")
            ok = ok and condition is not None
            decision = dataclasses.replace(decision, condition=condition)
        if kind == "repeat":
            bounds = self.repeat_bounds(item, where)
            ok = ok and bounds is not None
            times, most = bounds or (None, None)
            decision = dataclasses.replace(decision, times=times, most=most)
        if kind == "wait":
            if "timeout" in item:
                timeout = self.quantity(item["timeout"], item.value_loc("timeout"), TIME, f"timeout of {where}")
                ok = ok and timeout is not None
                decision = dataclasses.replace(decision, timeout=timeout)
            else:
                self.warn("W705", f"{where} has no timeout: it waits for ever if its condition never holds",
                          item.key_loc(kind), "add timeout: (e.g. 2 s): it then fails like a job, and a try can catch it")
        if not ok:
            return None
        step = ApplicationStep(kind, {}, item.key_loc(kind), decision=decision)
        return StepDraft(step, None, rows=tuple(rows))

    def decision_row(self, app: str, number: int, item: YMap, key: str, where: str, kind: str) -> tuple[StepDraft, ...] | None:
        value, loc = item[key], item.value_loc(key)
        if not isinstance(value, YList) or (not value and key != "else"):
            self.error("E720", f"{where}: '{key}:' must be a list of steps, got: {describe(value)}", location_of(value, loc),
                       f"e.g.\n{EXAMPLES[kind]}")
            return None
        checked = [self.check_step(app, number, inner, value.item_loc(i)) for i, inner in enumerate(value)]
        return None if any(c is None for c in checked) else tuple(c for c in checked if c is not None)

    def decision_condition(self, value: Any, loc: Location, what: str) -> str | None:
        """A condition of the job language over declared variables that computes on their shapes (E719,
        as a job's); a constant one warned."""
        text = self.check_expression(value, loc, what)
        if text is None:
            return None
        condition = compile_condition(text)
        if not condition.variables:
            self.warn("W704", f"{what} is constant: '{text}' reads no state variable", loc,
                      "a decision on a constant always goes the same way; name the variables it decides on")
            return text
        return text  # (check_expression computed it once on its variables' shapes: E719)

    def repeat_bounds(self, item: YMap, where: str) -> tuple[int | None, int | None] | None:
        """(times, max) of a repeat: `times: N`, or `until:` with `max: N`; unbounded is refused."""
        if ("times" in item) == ("until" in item) or ("until" in item) != ("max" in item):
            given = [key for key in ("times", "until", "max") if key in item]
            self.error("E721", f"{where} is not bounded: it has {', '.join(given) or 'neither times: nor until:'}",
                       item.key_loc("repeat"),
                       "give times: N, or until: \"CONDITION\" with max: N (the most times it runs before it fails)")
            return None
        key = "times" if "times" in item else "max"
        value = item[key]
        if not isinstance(value, int) or isinstance(value, bool) or value < 1:
            self.error("E721", f"{where}: {key}: must be a whole number of times from 1, got: {describe(value)}",
                       item.value_loc(key), "e.g. times: 3")
            return None
        return (value, None) if key == "times" else (None, value)

    def finish_decision(self, app: str, number: int, item: StepDraft, gaps: list[Gap]) -> ApplicationStep | None:
        """The step with its rows built, the applications they use known now; their gaps are the application's."""
        rows: list[tuple[ApplicationStep, ...]] = []
        for row in item.rows:
            built: list[ApplicationStep] = []
            for inner in row:
                step = self.finish_row_step(app, number, inner, gaps)
                if step is None:
                    return None
                built.append(step)
            rows.append(tuple(built))
        decision = item.step.decision
        assert decision is not None
        if decision.kind == "try" and not any(step_can_fail(self.out, step) for step in rows[0]):
            self.warn("W703", f"the try of step {number} of application '{app}' cannot fail: its fallback never runs",
                      item.step.loc, "a step fails by a pre-condition that does not hold, a post-condition not met within "
                                     "its job's timeout:, or a wait's timeout:; give one of its jobs a timeout:")
        return dataclasses.replace(item.step, decision=dataclasses.replace(decision, rows=tuple(rows)))

    def finish_row_step(self, app: str, number: int, inner: StepDraft, gaps: list[Gap]) -> ApplicationStep | None:
        step = inner.step
        if step.decision is not None:
            return self.finish_decision(app, number, inner, gaps)
        if not step.is_application:
            if inner.gap is not None:
                gaps.append(Gap(number, step.job, inner.gap))
            return step
        used = self.out.applications.get(step.job)
        if used is None:
            return None  # wrong itself, and reported there
        if inner.given is not None:
            return self.fill_application(app, number, used, inner)
        if used.gaps:
            gaps.append(Gap(number, step.job, used.object_type))
            self.warn(
                "W702",
                f"application '{app}' is incomplete: step {number} uses the incomplete application '{step.job}'",
                step.loc,
                f"fill the gaps of '{step.job}', or give it an object; an incomplete application may be kept but not run",
            )
        return step
