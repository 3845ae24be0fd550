"""What changes between consecutive jobs of an application: which tasks go off, which go on.

This is the dynamic reconfiguration plan of TR §4.4 worked out from the file alone, so
`pbo check` can show it and job control can apply it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from pbo_runtime.config.model import Subsystem


@dataclass(frozen=True)
class Transition:
    step: int  # the job being entered (1-based within the flattened application)
    job: str
    before: str | None  # configuration left (None: the first job)
    after: str
    off: tuple[str, ...]
    on: tuple[str, ...]
    stay: tuple[str, ...]


def flatten(subsystem: Subsystem, application: str, _seen: tuple[str, ...] = ()) -> list[str]:
    """The application's jobs in order, with applications used as steps expanded (Onika §4.4.2)."""
    if application in _seen:  # the checker reports cycles; never loop here
        return []
    jobs: list[str] = []
    for step in subsystem.applications[application].steps:
        if step.job in subsystem.jobs:
            jobs.append(step.job)
        elif step.job in subsystem.applications:
            jobs.extend(flatten(subsystem, step.job, (*_seen, application)))
    return jobs


def transitions(subsystem: Subsystem, application: str) -> list[Transition]:
    """One transition per job of the application, from the previous job's configuration."""
    return transitions_of(subsystem, flatten(subsystem, application))


def transitions_of(subsystem: Subsystem, jobs: Sequence[str]) -> list[Transition]:
    """One transition per job of `jobs` (one path of an application), from the previous job's configuration."""
    result = []
    previous: str | None = None
    for step, job in enumerate(jobs, start=1):
        configuration = subsystem.jobs[job].configuration
        before = set(subsystem.configurations[previous].tasks) if previous else set()
        after_tasks = subsystem.configurations[configuration].tasks
        order = [t for t in subsystem.init_order]
        result.append(Transition(
            step, job, previous, configuration,
            off=tuple(t for t in order if t in before and t not in after_tasks),
            on=tuple(t for t in order if t in after_tasks and t not in before),
            stay=tuple(t for t in order if t in before and t in after_tasks),
        ))
        previous = configuration
    return result
