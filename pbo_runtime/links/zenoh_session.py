"""A zenoh session for one end of a link: its endpoints, its configuration, opening it, finding the other end.

A session that listens is a router (the hub of its links); one that only connects is a client of
it. Sessions stay on the machine unless told otherwise and discover nothing by themselves: no
multicast scouting, no gossip, no shared memory segments, only the endpoints given
(`config_entries` lists every key set). They open after a fork, never before: zenoh's runtime
threads do not survive one. `SessionEnd` is what both kinds of link share: the session (own or
given), the entities declared on it, and the queryable through which an end describes itself.
"""

from __future__ import annotations

import contextlib
import json
import socket
import time
from collections.abc import Callable, Sequence
from typing import Any

import msgpack

from pbo_runtime.errors import PboError
from pbo_runtime.links.run_link import RunLink
from pbo_runtime.links.spec import parse_endpoint
from pbo_runtime.links.triple_buffer import LinkError

LOOPBACK = "127.0.0.1"
DEFAULT_WAIT = 5.0  # seconds an attaching end waits for the creating end's session (an application's message sender;
# its periodic reader does not wait: `wait=None`, it connects whenever the sender listens)
ANSWER_TIMEOUT = 1.0  # seconds a query of the other end's description waits for replies
CONNECT_RETRY = {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2}
RETRY_PERIOD = 0.05  # seconds between an attaching end's tries to reach the creating end


def zenoh_module() -> Any:
    """The zenoh module, imported when a zenoh link is first opened (a shm-only run does not need it)."""
    try:
        import zenoh
    except ImportError:
        raise LinkError("transport 'zenoh' needs the eclipse-zenoh package: pip install 'eclipse-zenoh>=1.0'") from None
    return zenoh




def endpoint(port: int, host: str = LOOPBACK) -> str:
    """The zenoh locator of a TCP port: 'tcp/127.0.0.1:7447'."""
    if not isinstance(port, int) or not 0 < port < 65536:
        raise LinkError(f"a zenoh link's port must be an integer in 1..65535, got: {port!r}")
    return f"tcp/{host}:{port}"


def free_port(host: str = LOOPBACK) -> int:
    """A TCP port nothing listens on now (for tests and benchmarks: another process may take it later)."""
    with socket.socket() as probe:
        probe.bind((host, 0))
        return int(probe.getsockname()[1])


def config_entries(listen: Sequence[str] = (), connect: Sequence[str] = (), background: bool = False) -> dict[str, Any]:
    """Every zenoh configuration key a session of ours sets, with its value (JSON).

    A session that listens is a router (the hub of its links: it forwards between the ends that
    connect to it, so two of them that do not listen still see each other); one that only
    connects is a client of it. `background`: a session that opens at once and connects to its
    endpoints whenever they answer (a peer that keeps trying), for an end whose other end may
    start later, on another machine.
    """
    entries = {
        "mode": "router" if listen else ("peer" if background else "client"),
        "listen/endpoints": list(listen),  # the default would be every interface
        "listen/exit_on_failure": True,  # a port in use fails the open instead of listening nowhere
        "connect/endpoints": list(connect),
        "connect/retry": dict(CONNECT_RETRY),  # how fast a client reconnects after its hub restarts
        "scouting/multicast/enabled": False,  # never discover peers by multicast...
        "scouting/gossip/enabled": False,  # ...nor learn of peers from other peers: only the endpoints above
        "scouting/delay": 0,  # nothing to scout for, so no reason to wait for it at open
        "transport/shared_memory/enabled": False,  # its segments outlive the process in /dev/shm
        "timestamping/enabled": False,  # items carry their own CLOCK_MONOTONIC stamps
        "adminspace/enabled": False,
    }
    if background:
        entries["connect/exit_on_failure"] = False  # nothing answers yet: open anyway...
        entries["connect/timeout_ms"] = -1  # ...and keep trying (connect/retry) for as long as the session lives
    return entries


def session_config(listen: Sequence[str] = (), connect: Sequence[str] = (), background: bool = False) -> Any:
    """A zenoh.Config with `config_entries`."""
    zenoh = zenoh_module()
    config = zenoh.Config()
    for key, value in config_entries(listen, connect, background).items():
        config.insert_json5(key, json.dumps(value))
    return config


def open_session(listen: Sequence[str] = (), connect: Sequence[str] = (), wait: float | None = 0.0) -> Any:
    """A zenoh session confined to the given endpoints (see `config_entries`).

    A client keeps trying to reach its hub for `wait` seconds (0: one try). `wait=None`: the session
    opens at once and connects in the background whenever the hub answers (never waits, never fails
    for want of it): an end whose other end starts later, maybe on another machine.
    """
    zenoh = zenoh_module()
    if wait is None and connect and not listen:
        return zenoh.open(session_config(listen, connect, background=True))
    config = session_config(listen, connect)
    give_up = None if wait is None else time.monotonic() + wait
    while True:
        try:
            return zenoh.open(config)
        except zenoh.ZError as exc:
            if listen:
                raise LinkError(f"cannot listen on {', '.join(listen)}: {exc} (is the port taken by another process?)") from None
            if give_up is not None and time.monotonic() >= give_up:
                raise LinkError(f"nothing answered on {', '.join(connect)}"
                                + (f" within {wait:g} s" if wait else "")) from None
        time.sleep(RETRY_PERIOD)


def endpoints(name: str, port: int | None, host: str, session: Any, listening: bool) -> tuple[list[str], list[str]]:
    """(listen, connect) of an end's own session; none when it was given a session."""
    if session is not None:
        if port is not None:
            raise LinkError(f"link '{name}': give either a port or a session, not both (a given session has its own endpoints)")
        return [], []
    if port is None:
        raise LinkError(f"link '{name}' uses transport 'zenoh' and needs a port (the creating end listens on it)")
    where = [endpoint(port, host)]
    return (where, []) if listening else ([], where)


def key_expression(name: str) -> str:
    """The zenoh key expression of a link's name: the name without a leading '/', no wildcards."""
    key = name.lstrip("/")
    if not key or any(c in key for c in "*$?#") or "//" in key or key.endswith("/"):
        raise LinkError(f"a zenoh link's name must be a key expression without wildcards ('a/b/c'), got: {name!r}")
    return key


def spec_endpoint(spec: RunLink) -> tuple[str, int]:
    """(host, port) of the link the application runner hands down (`links.ends`), or LinkError."""
    endpoint = parse_endpoint(spec.endpoint)
    if endpoint is None or not spec.key:
        raise LinkError(f"a zenoh link's spec needs 'key' and 'endpoint' ('tcp/<host>:<port>'), got: {spec.to_json()!r}")
    return endpoint


def link_key(application: str, link: str) -> str:
    """A link's key for both machines to agree on: 'pbo/<application>/<link>' (no run id in it)."""
    return key_expression(f"pbo/{application}/{link}")


class SessionEnd:
    """What the two kinds of link share: a session (own or given), its entities, the end queryable."""

    name: str
    key: str
    _session: Any  # a zenoh.Session; None once closed

    def _open_session(self, session: Any, listen: Sequence[str], connect: Sequence[str], wait: float | None = 0.0) -> None:
        self._entities: list[Any] = []
        self._session = None
        self._owns_session = session is None
        if session is None:
            try:
                session = open_session(listen, connect, wait)
            except LinkError as exc:
                if listen:
                    raise
                raise self._missing(str(exc)) from None
        self._session = session

    def _missing(self, detail: str) -> PboError:
        return LinkError(f"no link '{self.name}': {detail}: has the subsystem that creates it started?")

    def _answer_as(self, role: str, describe: Callable[[], dict[str, Any]]) -> None:
        """Answer queries on `<key>/end/<role>` with `describe()` (msgpack): who holds this end, with what.

        The one Python callback our ends leave in zenoh's threads: a query comes only when another
        end opens (set-up, a restart), and `describe` reads attributes without taking any lock a
        cycle takes; answering from a channel would need this end's owner to poll it, and an end
        whose owner is busy elsewhere would then look absent to the end that opens.
        """
        key = f"{self.key}/end/{role}"

        def answer(query: Any) -> None:
            with contextlib.suppress(Exception):  # a reply to a peer that left: nothing to tell anyone
                query.reply(key, msgpack.packb(describe()))

        self._entities.append(self._session.declare_queryable(key, answer))

    def _other_ends(self, selector: str) -> list[dict[str, Any]]:
        """The descriptions answered on `selector` by ends already open (none if nobody answers)."""
        found = []
        zenoh = zenoh_module()
        for reply in self._session.get(selector, target=zenoh.QueryTarget.ALL, timeout=ANSWER_TIMEOUT):
            if reply.ok is None:
                continue
            try:
                found.append(msgpack.unpackb(reply.ok.payload.to_bytes()))
            except (ValueError, msgpack.UnpackException):
                continue
        return found

    def close(self) -> None:
        """Undeclare this end and close its session (unless it was given one). Twice is harmless."""
        if getattr(self, "_session", None) is None:
            return
        try:
            self._close_session()
        finally:
            self._session = None
            self._forget()

    def _forget(self) -> None:
        """Drop what this end declared beside its session (its publisher, ...)."""

    def _close_session(self) -> None:
        entities, self._entities = self._entities, []
        for entity in reversed(entities):
            with contextlib.suppress(Exception):  # already undeclared by a closed session
                entity.undeclare()
        if self._owns_session and self._session is not None and not self._session.is_closed():
            self._session.close()
