"""How a subsystem is run: what `pbo run`'s options ask of the supervisor, typed and checked once."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from pbo_runtime.links.run_link import RunLink
from pbo_runtime.supervisor.failures import WrongArgument

PACE_RANGE = (0.01, 1000.0)  # `--pace`: from a hundredth of real time to a thousand times it


def pace_refused(pace: float | None, clock: str) -> str | None:
    """Why `--pace` cannot be `pace` on `clock`, or None when it can."""
    if pace is None:
        return None
    if clock != "sim":
        return "--pace slows the simulated clock; the real clock already runs at real time: add --clock sim"
    low, high = PACE_RANGE
    if not low <= pace <= high:  # (NaN fails both)
        return (f"--pace {pace:g} is out of range: give simulated seconds per wall second from {low:g} to {high:g} "
                "(1: real time)")
    return None


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
    pace: float | None = None  # sim: at most this many simulated seconds per wall second (None: as fast as it goes)
    out_dir: str | None = None  # where the modules write their files
    links: Mapping[str, RunLink] | None = None  # an application's links, handed to every RTPU
    turn: str | None = None  # an application on the simulated clock: the semaphores of this subsystem's turn
    stages: str | None = None  # an application file's stages: this subsystem's part and the joins
    # the start-up's time line before the supervisor (the CLI's imports, the file's load and check)
    startup: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.one_process and self.clock != "sim":
            raise WrongArgument("one process (--one-process) is for the simulated clock only: add --clock sim")
        refused = pace_refused(self.pace, self.clock)
        if refused:
            raise WrongArgument(refused)
