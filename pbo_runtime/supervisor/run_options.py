"""How a subsystem is run: what `pbo run`'s options ask of the supervisor, typed and checked once."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from pbo_runtime.config.decisions import decides, paths
from pbo_runtime.config.model import Subsystem
from pbo_runtime.errors import closest_name
from pbo_runtime.supervisor.failures import RunFailure, WrongArgument
from pbo_runtime.supervisor.job_control import application_steps


@dataclass(frozen=True)
class Alternation:
    """`pbo run --alternate`: switch between `configurations` `switches` times, `interval` seconds apart."""

    configurations: list[str]
    switches: int
    interval: float


@dataclass(frozen=True)
class RunOptions:
    """A run's options besides its configuration and duration (`Supervisor`); the defaults are `pbo run`'s."""

    application: str | None = None  # run this application's jobs (`--app`)
    static: bool = False  # static reconfiguration: only the running configuration's tasks exist
    alternate: Alternation | None = None
    fifo: bool | None = None  # SCHED_FIFO for the RTPUs; None: the clock's default
    clock: str = "real"  # "real", or "sim": the simulated clock, replayed bit for bit
    one_process: bool = False  # sim: the plant and every RTPU hosted in the supervisor's process
    out_dir: str | None = None  # where the modules write their files
    links: dict[str, dict[str, Any]] | None = None  # an application's links, handed to every RTPU
    turn: str | None = None  # an application on the simulated clock: the semaphores of this subsystem's turn
    stages: str | None = None  # an application file's stages: this subsystem's part and the joins
    # the start-up's time line before the supervisor (the CLI's imports, the file's load and check)
    startup: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.one_process and self.clock != "sim":
            raise WrongArgument("one process (--one-process) is for the simulated clock only: add --clock sim")


def starting_configuration(subsystem: Subsystem, configuration: str | None, application: str | None) -> str:
    """The configuration a run starts in: the one asked for, else the application's first job's, else
    the file's first; WrongArgument for a name the file does not have, RunFailure for an incomplete application."""
    if application is not None and application not in subsystem.applications:
        close = closest_name(application, subsystem.applications)
        raise WrongArgument(f"no application '{application}' in {subsystem.file}"
                            + (f": did you mean '{close}'?" if close else "")
                            + f" (applications: {', '.join(subsystem.applications) or 'none'})")
    if application is not None and not subsystem.applications[application].complete:
        raise RunFailure(f"application '{application}' is incomplete (a step lacks the object its job needs) and "
                         f"cannot be run; pbo check {subsystem.file} shows which step")
    if configuration is None and application is not None:
        first = [job for job, _ in application_steps(subsystem, application)]
        if decides(subsystem, application):  # the first job of its first path
            first = list(paths(subsystem, application)[0][0].jobs)
        configuration = subsystem.jobs[first[0]].configuration if first else None
    chosen = configuration or next(iter(subsystem.configurations))
    if chosen not in subsystem.configurations:
        close = closest_name(chosen, subsystem.configurations)
        raise WrongArgument(f"no configuration '{chosen}' in {subsystem.file}"
                            + (f": did you mean '{close}'?" if close else "")
                            + f" (configurations: {', '.join(subsystem.configurations)})")
    return chosen
