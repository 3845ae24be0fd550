"""How a task reaches an application's link: the spec job control hands down, and the end it opens.

The application runner (`supervisor.application_runner`) makes every link before the subsystems start and
passes each subsystem its links (`links.run_link.RunLink`, by name), which travel with `pbo run --links`
to the supervisor and then to each RTPU (`--links`), where `TaskContext.open_link` opens one end.

Roles: a periodic link has a 'sender' and a 'reader'; a message link a 'sender' and a 'server'
(whose end the RTPU watches, releasing the server task per message: `links.relay`).

The payload the task's port carries must be the link's: a mismatch is refused with both sides
named (the application checker reports it before anything runs; this is the runtime's guard).

`OPENERS` maps each transport to its openers, one per kind of link: adding a transport is one
entry there (and its name in `links.spec.TRANSPORTS`, which a test keeps equal to it).
`open_link` and `open_message_link` open an end by transport for a program that makes its own links.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from pbo_runtime.errors import ModuleError, require_extra
from pbo_runtime.links.message_link import SYSTEM_CAPACITY, SYSTEM_MESSAGE_BYTES
from pbo_runtime.links.run_link import RunLink
from pbo_runtime.links.spec import TRANSPORTS
from pbo_runtime.links.triple_buffer import LinkError, LinkLayout, Role
from pbo_runtime.links.zenoh_session import DEFAULT_WAIT, LOOPBACK

if TYPE_CHECKING:
    from pbo_runtime.links.message_link import MessageLink
    from pbo_runtime.links.triple_buffer import TripleBuffer
    from pbo_runtime.links.zenoh_link import ZenohLink
    from pbo_runtime.links.zenoh_message_link import ZenohMessageLink

Opener = Callable[[RunLink, np.ndarray, str], Any]  # (the link's spec, an item like the port's, role) -> end
# Each opener imports its transport when called: a subsystem that uses no zenoh link never loads zenoh.


def _shm_periodic(spec: RunLink, like: np.ndarray, role: str) -> Any:
    from pbo_runtime.links.triple_buffer import LinkLayout, TripleBuffer

    return TripleBuffer.attach(spec.shm_name, LinkLayout(like.dtype, like.shape), role=role)


def _zenoh_periodic(spec: RunLink, like: np.ndarray, role: str) -> Any:
    require_extra("zenoh", f"the zenoh link '{spec.key or '?'}'")
    from pbo_runtime.links import zenoh_link
    from pbo_runtime.links.triple_buffer import LinkLayout

    return zenoh_link.open_periodic(spec, LinkLayout(like.dtype, like.shape), role)


def _shm_message(spec: RunLink, _like: np.ndarray, _role: str) -> Any:
    """The runner made the queue: both ends attach."""
    from pbo_runtime.links.message_link import MessageLink

    return MessageLink.attach(spec.shm_name)


def _zenoh_message(spec: RunLink, _like: np.ndarray, role: str) -> Any:
    """The server listens on the spec's endpoint, the sender connects."""
    require_extra("zenoh", f"the zenoh link '{spec.key or '?'}'")
    from pbo_runtime.links import zenoh_message_link

    return zenoh_message_link.open_aperiodic(spec, role)


OPENERS: dict[str, dict[str, Opener]] = {  # transport -> kind of link -> how an end of it opens
    "shm": {"periodic": _shm_periodic, "message": _shm_message},
    "zenoh": {"periodic": _zenoh_periodic, "message": _zenoh_message},
}


def open_link_end(name: str, spec: RunLink, like: np.ndarray, role: str) -> Any:
    """The end of link `name` in `role`, for items shaped like `like`."""
    expected = (np.dtype(spec.dtype), spec.shape)
    if (like.dtype, like.shape) != expected:
        raise ModuleError(f"link '{name}' carries {expected[0]} {list(expected[1])}, but the port is {like.dtype} "
                          f"{list(like.shape)}: link a variable of the link's type and shape")
    transport = spec.transport
    if transport not in OPENERS:
        raise ModuleError(f"link '{name}': unknown transport '{transport}' (transports: {', '.join(OPENERS)})")
    kind = "message" if spec.kind == "message" else "periodic"
    if kind == "message" and role not in ("sender", "server"):
        raise ModuleError(f"link '{name}' carries messages: its ends are 'sender' and 'server', not '{role}'")
    return OPENERS[transport][kind](spec, like, role)


# --- an end by transport, for a program that opens its own links ---------------------------------


def open_link(transport: str, name: str, layout: LinkLayout, role: Role | str | None = None, *, create: bool,
              port: int | None = None, host: str = LOOPBACK, wait: float | None = DEFAULT_WAIT,
              session: Any = None) -> TripleBuffer | ZenohLink:
    """A periodic link's end over `transport` ('shm' or 'zenoh'); `create`: make it (shm) or listen (zenoh)."""
    from pbo_runtime.links.triple_buffer import TripleBuffer
    from pbo_runtime.links.zenoh_link import ZenohLink

    if _transport(transport) == "shm":
        _no_zenoh_options(name, port, session)
        return (TripleBuffer.create if create else TripleBuffer.attach)(name, layout, role)
    if create:
        return ZenohLink.create(name, layout, role, port=port, host=host, session=session)
    return ZenohLink.attach(name, layout, role, port=port, host=host, session=session, wait=wait)


def open_message_link(transport: str, name: str, *, create: bool, capacity: int = SYSTEM_CAPACITY,
                      max_message_bytes: int = SYSTEM_MESSAGE_BYTES, port: int | None = None, host: str = LOOPBACK,
                      wait: float | None = DEFAULT_WAIT, session: Any = None) -> MessageLink | ZenohMessageLink:
    """A message link's end over `transport`; `create` makes it (shm) or makes the receiving end (zenoh)."""
    from pbo_runtime.links.message_link import MessageLink
    from pbo_runtime.links.zenoh_message_link import ZenohMessageLink

    if _transport(transport) == "shm":
        _no_zenoh_options(name, port, session)
        return MessageLink.create(name, capacity, max_message_bytes) if create else MessageLink.attach(name)
    if create:
        return ZenohMessageLink.create(name, capacity, max_message_bytes, port=port, host=host, session=session)
    return ZenohMessageLink.attach(name, port=port, host=host, session=session, wait=wait)


def _transport(transport: str) -> str:
    if transport not in TRANSPORTS:
        raise LinkError(f"transport must be one of {', '.join(TRANSPORTS)}, got: {transport!r}")
    return transport


def _no_zenoh_options(name: str, port: int | None, session: Any) -> None:
    given = [what for what, value in (("port", port), ("session", session)) if value is not None]
    if given:
        raise LinkError(
            f"link '{name}' uses transport 'shm', which takes no {' or '.join(given)} (those are for transport 'zenoh')"
        )
