"""The run's POSIX objects: their names (the manifest), and the queues, each sized for what it carries:
the events, a signal queue per RTPU, the control queue."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from pbo_runtime.config.application import MESSAGE_OVERHEAD_BYTES, MSGPACK_BYTES_PER_NUMBER
from pbo_runtime.config.limits import MAX_NAME
from pbo_runtime.config.model import Subsystem
from pbo_runtime.ipc import limits, messages
from pbo_runtime.ipc.control import REQUEST_BYTES, control_queue_name, control_queue_size
from pbo_runtime.links.run_link import RunLink


def queue_plan(sub: Subsystem, run_id: str, links: Mapping[str, RunLink]) -> list[limits.QueueSize]:
    """The sizes of the run's queues, in the order they are made: events, each RTPU's signals, control."""
    plan = [messages.event_queue_size(messages.event_queue_name(sub.name, run_id),
                                      [[t.name for t in sub.tasks_on(rtpu.name)] for rtpu in sub.rtpus])]
    # what an aperiodic task's event may carry: an operator's values (a control request at most),
    # or a message of one of the application's links, as the checker bounds it
    payload = max([REQUEST_BYTES] + [MSGPACK_BYTES_PER_NUMBER * int(np.prod(link.shape)) + MESSAGE_OVERHEAD_BYTES
                                     for link in links.values() if link.kind == "message"])
    for rtpu in sub.rtpus:
        hosted = sub.tasks_on(rtpu.name)
        # (room for the longest name a task spawned live may have: `pbo spawn` may put one on any RTPU)
        plan.append(messages.signal_queue_size(messages.signal_queue_name(sub.name, run_id, rtpu.name),
                                               [t.name for t in hosted] + ["x" * MAX_NAME],
                                               payload if any(t.aperiodic for t in hosted) else 0))
    plan.append(control_queue_size(sub.name, run_id))
    return plan


def run_manifest(sub: Subsystem, run_id: str, semaphores: list[str]) -> list[str]:
    """Every shared object the run makes ("kind /name"), with the run clock's `semaphores`."""
    s, r = sub.name, run_id
    table = messages.table_name(s, r)
    entries = [f"shm {table}", f"sem {table}.lock", f"mq {messages.event_queue_name(s, r)}"]
    entries += [f"mq {messages.signal_queue_name(s, r, rtpu.name)}" for rtpu in sub.rtpus]
    if sub.plant is not None:
        entries.append(f"shm {messages.plant_registers_name(s, r)}")
    entries.append(f"mq {control_queue_name(s, r)}")
    entries += [f"sem {name}" for name in semaphores]
    return entries
