"""The sizes a configuration may not exceed, checked before anything is built from it.

A mistyped number (`NDOF: 1000000000000`), a generated file gone wrong or a hostile one must end
as a located error in `pbo check`, never as gigabytes allocated, a MemoryError or a wrong answer.
docs/configuration.md states each limit; each is far above what a control subsystem needs.
"""

from __future__ import annotations

# A YAML file (and each file it includes) is refused above this size before it is parsed: parsing
# costs about 120 bytes of memory per byte of YAML. The 10,002-task subsystem of the checker's
# benchmark is 2.7 MB.
MAX_FILE_BYTES = 4 * 1024 * 1024

# A name: the subsystem, an RTPU, a task, a variable, a configuration, a job, a device, ... The
# subsystem's name is part of every shared-memory object's name, and task names travel in signals
# and in queues sized for names this long.
MAX_NAME = 40

# A task's period (or min_interarrival): at least 10 us (a rate of at most 100 kHz), at most an hour
# (a rate of at least one cycle an hour). Beyond them a period is a typo or a unit mixed up, and
# the clock's integer nanoseconds would round it to nothing or overflow.
MIN_PERIOD = 10e-6
MAX_PERIOD = 3600.0

# Any other time a file gives (a job's timeout, a restart's window, a freshness bound, a timestep).
MAX_TIME = 86400.0

# A dim, or a size written in a shape.
MAX_DIM = 1 << 24

# The state variable table's data (every variable's elements), and so any one variable: the table
# is one shared-memory segment that every RTPU maps, and an `initial:` value is built in memory.
MAX_TABLE_BYTES = 64 * 1024 * 1024

# Integers in a job condition, written or computed: an integer power or product beyond this would
# wrap around in numpy's int64 and compare wrongly.
MAX_CONDITION_INT = 2**63 - 1


def show_bytes(count: int) -> str:
    """'4,194,304 bytes (4 MiB)': exact, then readable."""
    for unit, size in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if count >= size:
            return f"{count:,} bytes ({count / size:.3g} {unit})"
    return f"{count:,} bytes"
