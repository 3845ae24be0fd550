"""Subsystem interface, receiving end (TR §5.2): the newest item of a periodic link into a state variable.

Every cycle it copies the newest complete item into its output (the data is placed on its
output port, TR §5), and publishes how it fared: `link_lost` counts items the sender published
that this end never read (the sender is faster), `link_reused` cycles that found no new item
(the sender is slower), and `link_age` the age of what was read, in seconds, from the item's
time stamp on this machine's clock to this cycle's release (0 for an item published between the
release and the read). Before the first item arrives the output keeps its initial value.

`fresh_within` (seconds, 0: never) bounds how long it may go without a new item, judged on this
task's own clock from the cycle that got the last one (an arrival: no other machine's clock is
read). Past it, before the first item too, its cycle returns `Status.STABLE`: it says its input
is not fresh, and the critical tasks of its configuration run their locally stable behaviour
until a new item comes (docs/faults.md). Rewriting the last item would hide a partition from them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from modules._link_params import LinkParams
from pbo_runtime import ANY_DTYPE, OutVar, PortBasedObject, Status, param

NEW = 2  # what a link's read returns for an item newer than the last (links.triple_buffer.Freshness.NEW)


@dataclass(frozen=True)
class LinkReceiverParams(LinkParams):
    link: str  # the link's name in the application file's `links:`
    fresh_within: float = param(
        0.0, at_least=0, at_most=3600)  # s without a new item before the critical tasks hold; 0: never (the last item is kept)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.fresh_within, (int, float)) or isinstance(self.fresh_within, bool) \
                or not math.isfinite(self.fresh_within) or self.fresh_within < 0:
            raise ValueError(f"fresh_within must be seconds >= 0 (0: never), got: {self.fresh_within!r}")


class LinkReceiver(PortBasedObject):
    """Writes the newest item of `params.link` to `value` every cycle (`ports: {value: q_d}`)."""

    Params = LinkReceiverParams
    value = OutVar("value", dtype=ANY_DTYPE, shape=None, doc="the variable received from the other subsystem")
    counts = OutVar("link_counts", dtype="float64", shape=(3,),
                    doc="items lost (never read), cycles with no new item (reused), age of the item read (s)")

    def init(self, params: LinkReceiverParams) -> None:
        self._value, self._counts = self.bound_arrays[0], self.bound_arrays[1]
        self._link = self.open_link(params.link, self._value, role="reader")
        self._staging = np.zeros_like(self._value)  # read here, so the output keeps its value until an item came
        self._fresh_within = float(params.fresh_within) if params.fresh_within > 0 else math.inf
        self._new_at = -math.inf  # this task's time of the cycle that got the newest item (none yet)

    def on(self) -> None:
        self._new_at = -math.inf if self._link.counter == 0 else self.time  # a bound counts from now, not from before off

    def cycle(self) -> Status:
        link = self._link
        fresh = link.read(self._staging)
        if fresh:  # Freshness.NEW or REUSED: an item is there
            self._value[...] = self._staging
            counts = self._counts
            counts[0] = link.lost
            counts[1] = link.reused
            age = self.time - link.local_stamp_ns * 1e-9
            counts[2] = age if age > 0.0 else 0.0  # stamped after this cycle's release (before its read): fresh
            if fresh == NEW:
                self._new_at = self.time
        if self.time - self._new_at > self._fresh_within:
            return Status.STABLE  # no new item for too long: what this task writes is stale
        return Status.CONTINUE
