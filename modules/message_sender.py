"""Subsystem interface, aperiodic sending end (TR §5.1): a state variable sent as a message when it changes.

Each cycle it compares its input with what it last sent and, when they differ (and at its
first cycle, so the other side starts from this side's value), sends the value as a message on
the link `params.link`, at `params.priority`. It never waits: when the link's queue is full
(the server is not keeping up) the value stays pending and goes at a later cycle, and
`message_counts` says so. Sending is an event, not the per-cycle path: it allocates the
message (`tolist`, msgpack) only when the value changed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modules._link_params import LinkParams
from pbo_runtime import ANY_DTYPE, MAX_PRIORITY, InVar, LinkFullError, OutVar, PortBasedObject, Status, param


@dataclass(frozen=True)
class MessageSenderParams(LinkParams):
    priority: int = param(0, at_least=0, at_most=MAX_PRIORITY)  # 0..MAX_PRIORITY: the server takes higher priorities first
    every_cycle: bool = False  # send every cycle, changed or not (a heartbeat)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0 <= self.priority <= MAX_PRIORITY:
            raise ValueError(f"priority must be in 0..{MAX_PRIORITY}, got: {self.priority}")


class MessageSender(PortBasedObject):
    """Sends `value` on `params.link` when it changes (link it: `ports: {value: goal}`)."""

    Params = MessageSenderParams
    value = InVar("value", dtype=ANY_DTYPE, shape=None, doc="the variable sent to the other subsystem")
    counts = OutVar("message_counts", dtype="float64", shape=(2,),
                    doc="messages sent, and sends put off because the link's queue was full")

    def init(self, params: MessageSenderParams) -> None:
        self._value, self._counts = self.bound_arrays[0], self.bound_arrays[1]
        self._link = self.open_link(params.link, self._value, role="sender")
        self._priority = params.priority
        self._every_cycle = params.every_cycle
        self._sent = np.zeros_like(self._value)
        self._differs = np.zeros(self._value.shape, dtype=bool)
        self._pending = True  # the first cycle sends

    def cycle(self) -> Status:
        value = self._value
        if not self._pending and not self._every_cycle:
            np.not_equal(value, self._sent, out=self._differs)
            self._pending = bool(self._differs.any())
        if not (self._pending or self._every_cycle):
            return Status.CONTINUE
        try:
            self._link.send(value.tolist(), priority=self._priority, timeout=0.0)
        except LinkFullError:
            self._pending = True
            self._counts[1] += 1
            return Status.CONTINUE
        self._sent[...] = value
        self._pending = False
        self._counts[0] += 1
        return Status.CONTINUE
