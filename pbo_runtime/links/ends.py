"""How a task reaches an application's link: the spec job control hands down, and the end it opens.

The application runner (`supervisor.application_runner`) makes every link before the subsystems start and
passes each subsystem a JSON mapping, link name -> spec, which travels with `pbo run --links` to
the supervisor and then to each RTPU (`--links`), where `TaskContext.open_link` opens one end:

    {"transport": "shm", "object": "/pbo.<app>.<run id>.link-<name>", "dtype": "float64", "shape": [6]}
    {"transport": "zenoh", "key": "pbo/<app>/<name>", "endpoint": "tcp/127.0.0.1:<port>", ...}
    {"kind": "message", "transport": "shm", "object": "/pbo.<app>.<run id>.msg-<name>", "capacity": 8, ...}

Roles: a periodic link has a 'sender' and a 'reader'; a message link a 'sender' and a 'server'
(whose end the RTPU watches, releasing the server task per message: `links.relay`).

The payload the task's port carries must be the link's: a mismatch is refused with both sides
named (the application checker reports it before anything runs; this is the runtime's guard).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pbo_runtime.errors import ModuleError
from pbo_runtime.links.spec import TRANSPORTS

def open_link_end(name: str, spec: dict[str, Any], like: np.ndarray, role: str) -> Any:
    """The sender's or reader's end of link `name`, for items shaped like `like`."""
    from pbo_runtime.links.triple_buffer import LinkLayout

    expected = (np.dtype(spec["dtype"]), tuple(spec["shape"]))
    if (like.dtype, like.shape) != expected:
        raise ModuleError(f"link '{name}' carries {expected[0]} {list(expected[1])}, but the port is {like.dtype} "
                          f"{list(like.shape)}: link a variable of the link's type and shape")
    transport = spec.get("transport", "shm")
    if transport not in TRANSPORTS:
        raise ModuleError(f"link '{name}': unknown transport '{transport}' (transports: {', '.join(TRANSPORTS)})")
    if spec.get("kind", "periodic") == "message":
        return _open_message_end(name, spec, transport, role)
    layout = LinkLayout(like.dtype, like.shape)
    if transport == "shm":
        from pbo_runtime.links.triple_buffer import TripleBuffer

        return TripleBuffer.attach(spec["object"], layout, role=role)
    from pbo_runtime.links import zenoh_link

    return zenoh_link.open_periodic(spec, layout, role)


def _open_message_end(name: str, spec: dict[str, Any], transport: str, role: str) -> Any:
    """A message link's 'sender' or 'server' end; the runner made the shm queue, the zenoh server listens."""
    if role not in ("sender", "server"):
        raise ModuleError(f"link '{name}' carries messages: its ends are 'sender' and 'server', not '{role}'")
    if transport == "shm":
        from pbo_runtime.links.message_link import MessageLink

        return MessageLink.attach(spec["object"])
    from pbo_runtime.links import zenoh_link

    return zenoh_link.open_aperiodic(spec, role)
