"""Subsystem interface, receiving end (TR §5.2): the newest item of a periodic link into a state variable.

Every cycle it copies the newest complete item into its output (the data is placed on its
output port, TR §5), and publishes how it fared: `link_lost` counts items the sender published
that this end never read (the sender is faster), `link_reused` cycles that found no new item
(the sender is slower), and `link_age` the age of what was read, in seconds, from the sender's
time stamp to this cycle's release (0 for an item published between the release and the read).
Before the first item arrives the output keeps its initial value.
"""

from __future__ import annotations

import numpy as np

from modules._link_params import LinkParams
from pbo_runtime import ANY_DTYPE, OutVar, PortBasedObject, Status

LinkReceiverParams = LinkParams


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

    def cycle(self) -> Status:
        link = self._link
        fresh = link.read(self._staging)
        if fresh:  # Freshness.NEW or REUSED: an item is there
            self._value[...] = self._staging
            counts = self._counts
            counts[0] = link.lost
            counts[1] = link.reused
            age = self.time - link.stamp_ns * 1e-9
            counts[2] = age if age > 0.0 else 0.0  # stamped after this cycle's release (before its read): fresh
        return Status.CONTINUE
