"""Real-time settings of an RTPU process: CPU pinning, SCHED_FIFO, timer slack (docs/configuration.md).

Each is asked for and its outcome reported, never assumed: where the OS refuses (no permission,
a CPU the machine does not have), the RTPU runs on with what it got and says so in the summary.
"""

from __future__ import annotations

import os

from pbo_runtime.clock.clocks import lower_timer_slack
from pbo_runtime.supervisor.plant_host import PLANT_FIFO_PRIORITY

FIFO_PRIORITY = 50  # above ordinary processes, below the kernel's own real-time threads
# An RTPU hosting a critical task (a robot interface) preempts the others, as the executive runs a
# critical task first among its own: on two CPUs, another RTPU busy (or a killed one that the kernel
# tears down at its priority) does not hold the robot's cycle off. Below the plant (60).
CRITICAL_FIFO_PRIORITY = 55


def fifo_priority(hosts_critical: bool) -> int:
    return CRITICAL_FIFO_PRIORITY if hosts_critical else FIFO_PRIORITY


def apply(cpu: int | None, fifo: bool, priority: int = FIFO_PRIORITY) -> dict[str, str]:
    """Pin to `cpu` and switch to SCHED_FIFO at `priority` if asked; return what took effect, for the summary."""
    outcome = {"timer_slack": "1 ns" if lower_timer_slack() else "default (50 us): prctl refused"}
    if cpu is not None:
        try:
            os.sched_setaffinity(0, {cpu})
            outcome["cpu"] = str(cpu)
        except (OSError, ValueError) as exc:
            outcome["cpu"] = f"not pinned: CPU {cpu}: {exc}"
    else:
        outcome["cpu"] = "any"
    if fifo:
        try:
            # RESET_ON_FORK: a process a task starts (a log's encoder, a special-purpose processor)
            # begins at SCHED_OTHER. Inheriting SCHED_FIFO at the RTPU's priority, its interpreter's
            # start-up would hold the executive off its CPU.
            os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(priority))
            outcome["scheduler"] = f"SCHED_FIFO {priority}"
        except (OSError, AttributeError) as exc:
            outcome["scheduler"] = (f"SCHED_OTHER: SCHED_FIFO refused ({exc}); it needs CAP_SYS_NICE (root has it) "
                                    f"or a real-time priority limit (ulimit -r) of {PLANT_FIFO_PRIORITY}")
    else:
        outcome["scheduler"] = "SCHED_OTHER"
    return outcome
