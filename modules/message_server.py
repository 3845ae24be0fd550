"""Subsystem interface, aperiodic server (TR §5.1): a message from another subsystem into a state variable.

"A subsystem interfacing module is an aperiodic server, which waits for a message or signal from
the remote subsystem. When the signal is received, the aperiodic server executes its cycle
component" (TR §5.1). Run it with `aperiodic: true, min_interarrival: ...`: its RTPU relays each
message of `params.link` to the executive (`links.relay`), which releases the task with the
message in `event`; the cycle parses it into `value`, which the usual out-var transfer writes.
A message of the wrong size or with non-finite numbers is a fault (the task goes to ERROR; the
value keeps its last good message). Until the first message the output keeps its initial value.
"""

from __future__ import annotations

import numpy as np

from modules._link_params import LinkParams
from pbo_runtime import ANY_DTYPE, OutVar, PortBasedObject, Status

MessageServerParams = LinkParams


class MessageServer(PortBasedObject):
    """Writes each message of `params.link` to `value` (`ports: {value: q_d}`)."""

    Params = MessageServerParams
    value = OutVar("value", dtype=ANY_DTYPE, shape=None, doc="the variable the other subsystem's messages set")

    def init(self, params: MessageServerParams) -> None:
        self._value = self.bound_arrays[0]
        self._link_name = params.link
        self.open_link(params.link, self._value, role="server")

    def cycle(self) -> Status:
        event = self.event
        if event is None:
            return Status.CONTINUE
        body = event[0]
        try:
            values = np.asarray(body, dtype=self._value.dtype)
        except (TypeError, ValueError):
            return self.fault(f"a message on link '{self._link_name}' is not {self._value.dtype} numbers: {body!r}")
        if values.size != self._value.size or (values.dtype.kind == "f" and not np.all(np.isfinite(values))):
            return self.fault(f"a message on link '{self._link_name}' must hold {self._value.size} finite numbers, "
                              f"got: {body!r}")
        self._value[...] = values.reshape(self._value.shape)
        return Status.CONTINUE
