"""How a subsystem is run: what `pbo run`'s options ask of the supervisor, typed and checked once."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from pbo_runtime.links.run_link import RunLink
from pbo_runtime.supervisor.failures import WrongArgument


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
    links: Mapping[str, RunLink] | None = None  # an application's links, handed to every RTPU
    turn: str | None = None  # an application on the simulated clock: the semaphores of this subsystem's turn
    stages: str | None = None  # an application file's stages: this subsystem's part and the joins
    # the start-up's time line before the supervisor (the CLI's imports, the file's load and check)
    startup: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.one_process and self.clock != "sim":
            raise WrongArgument("one process (--one-process) is for the simulated clock only: add --clock sim")
