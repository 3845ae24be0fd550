"""The simulated clock's tick for a subsystem, checked against its periods."""

from __future__ import annotations

import math

from pbo_runtime.config.model import Subsystem
from pbo_runtime.supervisor.failures import RunFailure


def simulation_tick(subsystem: Subsystem) -> float:
    """The simulated clock's tick: the plant's timestep, or else the periods' greatest common divisor.

    Every period must be a whole number of ticks, or a task would be released between ticks.
    """
    periods_ns = {name: round(task.period * 1e9) for name, task in subsystem.tasks.items()}
    if subsystem.plant is not None:
        tick_ns = round(subsystem.plant.timestep * 1e9)
        off_grid = [f"{name} ({ns / 1e6:g} ms)" for name, ns in periods_ns.items() if ns % tick_ns]
        if off_grid:
            raise RunFailure(f"--clock sim steps the plant every {tick_ns / 1e6:g} ms and releases tasks on those ticks, "
                             f"but these periods are not whole multiples of it: {', '.join(off_grid)}; "
                             f"make each period a multiple of the plant's timestep")
        return tick_ns / 1e9
    return math.gcd(*periods_ns.values()) / 1e9
