"""Subsystem interface, sending end (TR §5.2): one state variable of this subsystem onto a periodic link.

Every cycle it copies its input into the link's free slot and publishes it with the cycle's
release time; it never waits for the reader. The link is declared in the application file
(`links:`) that runs this subsystem with others; `params.link` names it. Its payload is the
linked variable's dtype and shape, which the application checker matched against the link.
"""

from __future__ import annotations

from modules._link_params import LinkParams
from pbo_runtime import ANY_DTYPE, InVar, PortBasedObject, Status

LinkSenderParams = LinkParams


class LinkSender(PortBasedObject):
    """Publishes `value` on the link `params.link` every cycle (link it: `ports: {value: q_m}`)."""

    Params = LinkSenderParams
    value = InVar("value", dtype=ANY_DTYPE, shape=None, doc="the variable sent to the other subsystem")

    def init(self, params: LinkSenderParams) -> None:
        self._value = self.bound_arrays[0]
        self._link = self.open_link(params.link, self._value, role="sender")
        self._write = self._link.write

    def cycle(self) -> Status:
        self._write(self._value, stamp_ns=int(self.time * 1e9))
        return Status.CONTINUE
