"""Applications that decide (DESIGN §16): the paths an application may take, and which steps can fail.

A step of `applications:` is a job, an application, or one of the steps that decide:

    - if: "norm(q_m - q_d) < 0.05"     # then: runs when the condition holds, else: (optional) when not
      then: [settle: ready]
      else: [reach: ready, settle: ready]
    - try: [reach: far]               # a failure inside (a pre-condition, a timeout) runs fallback:
      fallback: [reach: ready]        # and the application goes on after it
    - repeat: [reach: ready, reach: home]
      times: 3                        # or until: "CONDITION" with max: N (failing when still false after N)
    - wait: "max(abs(qd_m)) < 0.01"   # a condition, with timeout: (failing like a job)
      timeout: 2 s

The checker (`checker.decisions`) treats every path as a sequence; `paths` lists them, so `pbo
check` prints the switches each path makes. Job control takes the decisions at run time
(`supervisor.decisions`).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from pbo_runtime.config.model import ApplicationStep, Subsystem

MAX_PATHS = 32  # paths listed per application: beyond, the table says how many were left out


@dataclass(frozen=True)
class Path:
    """One way through an application: how it goes at each decision, and the jobs it runs in order."""

    label: str  # e.g. "if: else, try: fails at 'reach' -> fallback" ("" for a sequence)
    jobs: tuple[str, ...]


def decides(subsystem: Subsystem, application: str, _seen: tuple[str, ...] = ()) -> bool:
    """True if the application, or one it uses, has a step that decides."""
    if application in _seen or application not in subsystem.applications:
        return False
    return any(step.decision is not None
               or (step.is_application and decides(subsystem, step.job, (*_seen, application)))
               for step in subsystem.applications[application].steps)


def paths(subsystem: Subsystem, application: str) -> tuple[list[Path], int]:
    """The application's paths (at most MAX_PATHS of them), and how many there are in all."""
    found = _row(subsystem, subsystem.applications[application].steps, (application,))
    every = [Path(", ".join(part for part in labels if part), jobs) for labels, jobs in found]
    return every[:MAX_PATHS], len(every)


_Way = tuple[tuple[str, ...], tuple[str, ...]]  # (labels of its decisions, jobs)


def _row(subsystem: Subsystem, steps: Iterable[ApplicationStep], seen: tuple[str, ...]) -> list[_Way]:
    ways: list[_Way] = [((), ())]
    for step in steps:
        options = _step(subsystem, step, seen)
        ways = [((*a[0], *b[0]), (*a[1], *b[1])) for a, b in itertools.product(ways, options)]
        del ways[MAX_PATHS * 4:]  # enough to count past the listed ones without growing without end
    return ways


def _step(subsystem: Subsystem, step: ApplicationStep, seen: tuple[str, ...]) -> list[_Way]:
    decision = step.decision
    if decision is None:
        if step.is_application:
            return [] if step.job in seen else _row(subsystem, subsystem.applications[step.job].steps, (*seen, step.job))
        return [((), (step.job,))]
    if decision.kind == "wait":
        return [((), ())]
    if decision.kind == "if":
        then, otherwise = decision.rows
        return ([(("if: then", *labels), jobs) for labels, jobs in _row(subsystem, then, seen)]
                + [(("if: else", *labels), jobs) for labels, jobs in _row(subsystem, otherwise, seen)])
    if decision.kind == "try":
        body, fallback = decision.rows
        ways = []
        for labels, jobs in _row(subsystem, body, seen):
            ways.append((("try: ok", *labels), jobs))
            for at, job in enumerate(jobs):
                if job_can_fail(subsystem, job):
                    for after_labels, after in _row(subsystem, fallback, seen):
                        ways.append(((f"try: fails at '{job}' -> fallback", *after_labels), (*jobs[:at + 1], *after)))
        return ways
    body_ways = _row(subsystem, decision.rows[0], seen)
    runs = decision.times if decision.times is not None else decision.most or 1
    if runs < 2:
        return [(("repeat", *labels), jobs) for labels, jobs in body_ways]
    # twice shows every switch a repeat makes: into the body, inside it, and from its end back to its start
    return [(("repeat", *a[0], *b[0]), (*a[1], *b[1])) for a, b in itertools.product(body_ways, body_ways)]


def job_can_fail(subsystem: Any, job: str) -> bool:
    """A job fails when its pre-condition does not hold, or its post-condition not within its timeout."""
    spec = subsystem.jobs[job]
    return bool(spec.pre) or bool(spec.post and spec.timeout)


def step_can_fail(subsystem: Any, step: ApplicationStep, _seen: tuple[str, ...] = ()) -> bool:
    """Whether a step can fail, and so send a `try` to its fallback."""
    decision = step.decision
    if decision is None:
        if step.is_application:
            spec = subsystem.applications.get(step.job)
            return spec is not None and step.job not in _seen and any(
                step_can_fail(subsystem, inner, (*_seen, step.job)) for inner in spec.steps)
        return step.job in subsystem.jobs and job_can_fail(subsystem, step.job)
    if decision.kind == "wait":
        return decision.timeout is not None
    if decision.kind == "repeat" and decision.condition is not None:
        return True  # still false after max: times
    rows = decision.rows[1:] if decision.kind == "try" else decision.rows
    return any(step_can_fail(subsystem, inner, _seen) for row in rows for inner in row)
