"""Links between subsystems over eclipse-zenoh: the same API and semantics as in shared memory.

When an application outgrows one machine its links run over Zenoh, chosen per link in the YAML
(`transport: shm | zenoh`). `ZenohLink` is a periodic link like `links.triple_buffer.TripleBuffer`
(the sender puts each item as one express `put` and never waits; the reader keeps the newest
complete item), `ZenohMessageLink` an aperiodic one like `links.message_link.MessageLink` (the
queue lives at the receiver; a sender has a window of `capacity` messages, refilled by credits).
`open_link` and `open_message_link` pick the transport; `open_periodic` and `open_aperiodic` open
an end from the spec the application runner hands down (`links.ends`).

Sessions stay on the machine unless told otherwise (`config_entries` lists every key set), and
open after a fork, never before: zenoh's runtime threads do not survive one. What differs from
shared memory, and why, the reader's two deliveries and their measured latencies:
docs/subsystems.md, "Links over Zenoh".
"""

from __future__ import annotations

import heapq
import itertools
import json
import os
import socket
import struct
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import msgpack
import numpy as np

from pbo_runtime.errors import PboError
from pbo_runtime.links.spec import TRANSPORTS, parse_endpoint
from pbo_runtime.links.message_link import (
    SYSTEM_CAPACITY,
    SYSTEM_MESSAGE_BYTES,
    LinkFullError,
    Message,
    MessageLink,
    MessageLinkError,
    encode_message,
)
from pbo_runtime.links.triple_buffer import (
    Freshness,
    ReaderTally,
    LinkError,
    LinkLayout,
    LinkLayoutError,
    LinkStatistics,
    Role,
    TripleBuffer,
    _role,
)

LOOPBACK = "127.0.0.1"
DEFAULT_WAIT = 5.0  # seconds an attaching end waits for the creating end's session (an application's message sender;
# its periodic reader does not wait: `wait=None`, it connects whenever the sender listens)
ANSWER_TIMEOUT = 1.0  # seconds a query of the other end's description waits for replies
ITEM_FORMAT = 0x5042_4F5F_5A4E_0001  # "PBO_ZN", wire format 1: the first word of every item
ITEM_HEADER = struct.Struct("<qqqqqq")  # format, layout hash, sender epoch, counter, stamp ns, reserved
MESSAGE_FORMAT = 1
DELIVERIES = ("ring", "callback")  # how a reader gets items from zenoh (see the module's docstring)
CONNECT_RETRY = {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2}
RETRY_PERIOD = 0.05  # seconds between an attaching end's tries to reach the creating end
PERIODIC_PRIORITY = "REAL_TIME"  # zenoh.Priority of periodic items: the highest data priority
MESSAGE_PRIORITY = "INTERACTIVE_HIGH"  # of messages and credits: above bulk data, below periodic items


def _zenoh() -> Any:
    """The zenoh module, imported when a zenoh link is first opened (a shm-only run does not need it)."""
    try:
        import zenoh
    except ImportError:
        raise LinkError("transport 'zenoh' needs the eclipse-zenoh package: pip install 'eclipse-zenoh>=1.0'") from None
    return zenoh


# --- sessions -------------------------------------------------------------------------------------


def endpoint(port: int, host: str = LOOPBACK) -> str:
    """The zenoh locator of a TCP port: 'tcp/127.0.0.1:7447'."""
    if not isinstance(port, int) or not 0 < port < 65536:
        raise LinkError(f"a zenoh link's port must be an integer in 1..65535, got: {port!r}")
    return f"tcp/{host}:{port}"


def free_port(host: str = LOOPBACK) -> int:
    """A TCP port nothing listens on now (for tests and benchmarks: another process may take it later)."""
    with socket.socket() as probe:
        probe.bind((host, 0))
        return probe.getsockname()[1]


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
    zenoh = _zenoh()
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
    zenoh = _zenoh()
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


def _endpoints(name: str, port: int | None, host: str, session: Any, listening: bool) -> tuple[list[str], list[str]]:
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


def link_key(application: str, link: str) -> str:
    """A link's key for both machines to agree on: 'pbo/<application>/<link>' (no run id in it)."""
    return key_expression(f"pbo/{application}/{link}")


class _Ends:
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

    def _answer_as(self, role: str, describe: Callable[[], dict]) -> None:
        """Answer queries on `<key>/end/<role>` with `describe()` (msgpack): who holds this end, with what."""
        key = f"{self.key}/end/{role}"

        def answer(query: Any) -> None:
            try:
                query.reply(key, msgpack.packb(describe()))
            except Exception:  # noqa: BLE001 - a reply to a peer that left: nothing to tell anyone
                pass

        self._entities.append(self._session.declare_queryable(key, answer))

    def _other_ends(self, selector: str) -> list[dict]:
        """The descriptions answered on `selector` by ends already open (none if nobody answers)."""
        found = []
        zenoh = _zenoh()
        for reply in self._session.get(selector, target=zenoh.QueryTarget.ALL, timeout=ANSWER_TIMEOUT):
            if reply.ok is None:
                continue
            try:
                found.append(msgpack.unpackb(reply.ok.payload.to_bytes()))
            except (ValueError, msgpack.UnpackException):
                continue
        return found

    def _close_session(self) -> None:
        entities, self._entities = self._entities, []
        for entity in reversed(entities):
            try:
                entity.undeclare()
            except Exception:  # noqa: BLE001 - already undeclared by a closed session
                pass
        if self._owns_session and self._session is not None and not self._session.is_closed():
            self._session.close()


# --- the periodic link ----------------------------------------------------------------------------


class ZenohLink(_Ends, ReaderTally):
    """One process's end of a periodic link over zenoh. `create` listens; `attach` connects."""

    transport = "zenoh"

    def __init__(self, name: str, layout: LinkLayout, owner: bool, delivery: str = "ring") -> None:
        if delivery not in DELIVERIES:
            raise LinkError(f"link '{name}': delivery must be one of {', '.join(DELIVERIES)}, got: {delivery!r}")
        self.delivery = delivery
        self.layout = layout
        self.name = name
        self.key = key_expression(name)
        self.owner = owner
        self.role: Role | None = None
        self._is_sender = self._is_reader = False
        self._pid = os.getpid()
        # sender: one wire buffer, header then payload, filled in place and put as it is
        self._wire = bytearray(ITEM_HEADER.size + layout.nbytes)
        self._words = np.frombuffer(self._wire, dtype="<i8", count=ITEM_HEADER.size // 8)
        self._payload = np.frombuffer(self._wire, dtype=layout.dtype, count=layout.size, offset=ITEM_HEADER.size).reshape(layout.shape)
        self._layout_hash = layout.layout_hash  # computed once: the property hashes the layout's text at each use
        self._words[:3] = (ITEM_FORMAT, self._layout_hash, int.from_bytes(os.urandom(7), "little"))
        self._publisher: Any = None
        self._published = 0
        self._writes = 0
        # reader: the slot the callback fills, under the lock
        self._lock = threading.Lock()
        self._newest: tuple[bytes, int, int, int, int] | None = None  # raw item, counter, stamp ns, received ns, local stamp ns
        # The sender's clock is not ours (another machine): its stamps are moved onto this clock by
        # the smallest (arrival - stamp) seen from the current sender: its clock offset plus the
        # quickest transfer. An item's local stamp is then when it would have arrived at its quickest.
        self._clock_offset_ns: int | None = None
        self._ring: Any = None  # delivery "ring": the subscriber whose one-sample ring read() drains
        self._newest_epoch = 0
        self._offset = 0  # added to the current sender's counters (see _take_item)
        self._foreign: tuple[int, int, int] | None = None  # format, layout hash, size of an item of another layout
        self._source: bytes | None = None
        self._view: np.ndarray | None = None
        self.value = np.zeros(layout.shape, dtype=layout.dtype)  # the reader's copy of the last item read
        self.counter = 0
        self.stamp_ns = 0
        self.local_stamp_ns = 0  # the same moment on this process's clock (see read)
        self.received_ns = 0  # when the last item read was taken from zenoh in this process (CLOCK_MONOTONIC ns)
        self.lost_in_last_read = 0
        self._before_first = 0
        self._new = self._reused = self._lost = self._empty = self._contended = 0

    # --- life -------------------------------------------------------------------------------

    @classmethod
    def create(cls, name: str, layout: LinkLayout, role: Role | str | None = None, *, port: int | None = None,
               host: str = LOOPBACK, session: Any = None, delivery: str = "ring") -> ZenohLink:
        """Listen on `tcp/<host>:<port>` (or use `session`) and optionally take one end (`delivery`: see the module)."""
        listen, connect = _endpoints(name, port, host, session, listening=True)
        return cls._open(name, layout, role, True, session, listen, connect, 0, delivery)

    @classmethod
    def attach(cls, name: str, layout: LinkLayout, role: Role | str | None = None, *, port: int | None = None,
               host: str = LOOPBACK, session: Any = None, wait: float | None = DEFAULT_WAIT,
               delivery: str = "ring") -> ZenohLink:
        """Connect to the creating end's `tcp/<host>:<port>` (or use `session`), trying for up to `wait` s.

        `wait`: 0 one try; None: do not wait, connect in the background whenever the creating end
        appears (a reader then reads NONE until the first item comes).
        """
        listen, connect = _endpoints(name, port, host, session, listening=False)
        return cls._open(name, layout, role, False, session, listen, connect, wait, delivery)

    @classmethod
    def _open(cls, name: str, layout: LinkLayout, role: Role | str | None, owner: bool, session: Any, listen: list[str],
              connect: list[str], wait: float | None, delivery: str) -> ZenohLink:
        role = _role(role)
        link = cls(name, layout, owner, delivery)
        link._open_session(session, listen, connect, wait)
        try:
            if role is not None:
                link._claim(role)
        except BaseException:
            link._close_session()
            raise
        return link

    def close(self) -> None:
        """Undeclare this end and close its session (unless it was given one). Twice is harmless."""
        if getattr(self, "_session", None) is None:
            return
        try:
            self._close_session()
        finally:
            self._session = None
            self._publisher = self._ring = None
            self._set_role(None)

    def unlink(self) -> None:
        """Nothing to remove: a zenoh link leaves no name behind (kept for the shm link's interface)."""

    def __enter__(self) -> ZenohLink:
        return self

    def __exit__(self, *_exc) -> None:
        self.close()

    # --- roles --------------------------------------------------------------------------------

    def _claim(self, role: Role) -> None:
        for other in self._other_ends(f"{self.key}/end/*"):
            if other.get("layout_hash") != self._layout_hash:
                raise LinkLayoutError(self._mismatch(other.get("layout", "another payload")))
            if other.get("role") == role.value:
                raise LinkError(f"link '{self.name}' already has a {role}: pid {other.get('pid')} on {other.get('host')} "
                                "(a link has one sender and one reader)")
            if role is Role.SENDER and other.get("role") == Role.READER.value:
                self._published = int(other.get("counter", 0))  # go on from the reader's newest, as a shm sender taking over
        zenoh = _zenoh()
        if role is Role.SENDER:
            self._publisher = self._session.declare_publisher(
                f"{self.key}/item",
                congestion_control=zenoh.CongestionControl.DROP,  # the sender never waits for the reader
                priority=getattr(zenoh.Priority, PERIODIC_PRIORITY),
                express=True,  # sent at once, not batched with later items
            )
            self._entities.append(self._publisher)
        else:
            if self.delivery == "ring":
                self._ring = self._session.declare_subscriber(f"{self.key}/item", zenoh.handlers.RingChannel(1))
                self._entities.append(self._ring)
            else:
                self._entities.append(self._session.declare_subscriber(f"{self.key}/item", self._on_sample))
        self._answer_as(role.value, self._describe)
        self._set_role(role)

    def _describe(self) -> dict:
        counter = self._published if self._is_sender else (self._newest[1] if self._newest else 0)
        return {"role": self.role.value if self.role else None, "pid": self._pid, "host": socket.gethostname(),
                "layout_hash": self._layout_hash, "layout": self.layout.description, "counter": counter}

    def _set_role(self, role: Role | None) -> None:
        self.role = role
        self._is_sender = role is Role.SENDER
        self._is_reader = role is Role.READER

    def _refuse(self, role: Role, action: str) -> None:
        held = f"as its {self.role}" if self.role else "with no role"
        raise LinkError(f"cannot {action} link '{self.name}': this process opened it {held}; only its {role} may")

    def _mismatch(self, found: str) -> str:
        return f"link '{self.name}' carries {found}, this process expects {self.layout.description}: do both ends declare the same payload?"

    # --- the sender ---------------------------------------------------------------------------

    def begin_write(self) -> np.ndarray:
        """The next item's payload, as a view to fill in place; `publish` sends it."""
        if not self._is_sender:
            self._refuse(Role.SENDER, "write")
        return self._payload

    def publish(self, stamp_ns: int | None = None) -> int:
        """Send the item filled since `begin_write`; return its counter. `stamp_ns` defaults to now."""
        if not self._is_sender:
            self._refuse(Role.SENDER, "publish")
        return self._publish(time.monotonic_ns() if stamp_ns is None else stamp_ns)

    def write(self, value, stamp_ns: int | None = None) -> int:
        """Copy `value` into the item and send it; return its counter. `stamp_ns` defaults to the call's time."""
        if not self._is_sender:
            self._refuse(Role.SENDER, "write")
        if stamp_ns is None:
            stamp_ns = time.monotonic_ns()
        np.copyto(self._payload, value)
        return self._publish(stamp_ns)

    def _publish(self, stamp_ns: int) -> int:
        counter = self._published + 1
        words = self._words
        words[3] = counter
        words[4] = stamp_ns
        self._publisher.put(self._wire)  # copied by zenoh: the buffer is ours again at return
        self._published = counter
        self._writes += 1
        return counter

    # --- the reader ---------------------------------------------------------------------------

    def _on_sample(self, sample: Any) -> None:
        self._take_item(sample.payload.to_bytes(), time.monotonic_ns())

    def _take_item(self, raw: bytes, received_ns: int) -> None:
        """The subscriber's callback: keep `raw` if it is a newer complete item of our layout."""
        if len(raw) != len(self._wire):
            head = struct.unpack_from("<qq", raw) if len(raw) >= 16 else (0, 0)
            with self._lock:
                self._foreign = (head[0], head[1], len(raw))
            return
        form, layout_hash, epoch, counter, stamp_ns, _ = ITEM_HEADER.unpack_from(raw)
        if form != ITEM_FORMAT or layout_hash != self._layout_hash:
            with self._lock:
                self._foreign = (form, layout_hash, len(raw))
            return
        with self._lock:
            newest = self._newest
            if epoch != self._newest_epoch:
                # Another sender (a restart, or one that could not ask the reader where to go on
                # from): renumber its items onto this reader's counter, which never goes back.
                held = newest[1] if newest is not None else 0
                self._offset = max(0, held - counter + 1)
                self._newest_epoch = epoch
                self._clock_offset_ns = None  # another sender: another clock
            counter += self._offset
            offset = received_ns - stamp_ns
            if self._clock_offset_ns is None or offset < self._clock_offset_ns:
                self._clock_offset_ns = offset
            local_ns = stamp_ns + self._clock_offset_ns
            if newest is None:
                self._before_first = counter - 1
            elif counter <= newest[1]:
                return  # not newer than the item held (a duplicate): keep the newest
            self._newest = (raw, counter, stamp_ns, received_ns, local_ns)

    def read(self, out: np.ndarray | None = None) -> Freshness:
        """Copy the newest item received into `out` (default: `self.value`) and say what it was.

        As for the triple buffer: `self.counter`, `self.stamp_ns` and `self.lost_in_last_read`
        describe the item; NONE leaves `out` as it was. Never waits for the network. `stamp_ns`
        is the sender's, on the sender's clock (another machine's, maybe); `local_stamp_ns` is the
        same moment on this process's CLOCK_MONOTONIC, moved by the offset the link estimates
        (see `_clock_offset_ns`): ages are judged from it, never from the other machine's clock.
        """
        if not self._is_reader:
            self._refuse(Role.READER, "read")
        if self._ring is not None:
            sample = self._ring.try_recv()  # the newest sample zenoh kept, if one came since the last read
            if sample is not None:
                self._take_item(sample.payload.to_bytes(), time.monotonic_ns())
        lock = self._lock
        if not lock.acquire(False):
            self._contended += 1
            lock.acquire()
        try:
            newest, foreign = self._newest, self._foreign
        finally:
            lock.release()
        if foreign is not None:
            raise LinkLayoutError(self._foreign_problem(foreign))
        if newest is None:
            self._empty += 1
            return Freshness.NONE
        raw, counter, stamp_ns, received_ns, local_ns = newest
        if raw is not self._source:  # a view per item received, none per read
            self._view = np.frombuffer(raw, dtype=self.layout.dtype, count=self.layout.size, offset=ITEM_HEADER.size).reshape(self.layout.shape)
            self._source = raw
        np.copyto(self.value if out is None else out, self._view)  # type: ignore[arg-type]  # set with _source
        freshness = self._tally(counter, stamp_ns)
        if freshness is Freshness.NEW:
            self.received_ns = received_ns
            self.local_stamp_ns = local_ns
        return freshness

    def _foreign_problem(self, foreign: tuple[int, int, int]) -> str:
        form, layout_hash, size = foreign
        if form != ITEM_FORMAT:
            return f"link '{self.name}' received an item that is not a pbo zenoh item of format {ITEM_FORMAT & 0xFFFF} ({size} bytes)"
        found: list[Any] = [o.get("layout") for o in self._other_ends(f"{self.key}/end/sender") if o.get("layout_hash") == layout_hash]
        return self._mismatch(found[0] if found else f"items of {size - ITEM_HEADER.size} bytes of another payload")

    def statistics(self) -> LinkStatistics:
        return LinkStatistics(writes=self._writes, new=self._new, reused=self._reused, lost=self._lost, empty=self._empty,
                              contended=self._contended, lock_recoveries=0)


# --- the message link -----------------------------------------------------------------------------


class ZenohMessageLink(_Ends):
    """One process's end of an aperiodic link over zenoh. `create` makes the receiving end; `attach` a sender."""

    transport = "zenoh"

    def __init__(self, name: str, owner: bool, capacity: int, max_message_bytes: int) -> None:
        self.name = name
        self.key = key_expression(name)
        self.owner = owner
        self.capacity = capacity
        self.max_message_bytes = max_message_bytes
        self._id = int.from_bytes(os.urandom(7), "little")
        self._room = threading.Condition()  # guards everything below
        self._sent = self._consumed = 0  # this end's messages sent, and taken by the receiver's receive()
        self._queue: list[tuple[int, int, int, int, Any]] = []  # receiver: (-priority, arrival, sender, sent ns, body)
        self._arrival = itertools.count()
        self._consumed_by: dict[int, int] = {}  # receiver: per sender id
        self._malformed = 0
        self._publisher: Any = None

    @classmethod
    def create(cls, name: str, capacity: int = SYSTEM_CAPACITY, max_message_bytes: int = SYSTEM_MESSAGE_BYTES, *,
               port: int | None = None, host: str = LOOPBACK, session: Any = None) -> ZenohMessageLink:
        """The receiving end, holding the queue: listens on `tcp/<host>:<port>` (or uses `session`)."""
        if capacity < 1:
            raise MessageLinkError(f"message link '{name}': capacity must be >= 1, got: {capacity}")
        if max_message_bytes < 16:
            raise MessageLinkError(f"message link '{name}': max_message_bytes must be >= 16, got: {max_message_bytes}")
        listen, connect = _endpoints(name, port, host, session, listening=True)
        link = cls(name, True, capacity, max_message_bytes)
        link._open_session(session, listen, connect)
        try:
            link._entities.append(link._session.declare_subscriber(f"{link.key}/message", link._on_message))
            link._answer_as("receiver", link._describe)
        except BaseException:
            link._close_session()
            raise
        return link

    @classmethod
    def attach(cls, name: str, *, port: int | None = None, host: str = LOOPBACK, session: Any = None,
               wait: float | None = DEFAULT_WAIT) -> ZenohMessageLink:
        """A sending end: connects to the receiver's `tcp/<host>:<port>` (or uses `session`) and learns its capacity."""
        zenoh = _zenoh()
        listen, connect = _endpoints(name, port, host, session, listening=False)
        link = cls(name, False, 0, 0)
        link._open_session(session, listen, connect, wait)
        try:
            receivers = [e for e in link._other_ends(f"{link.key}/end/receiver") if e.get("format") == MESSAGE_FORMAT]
            if not receivers:
                where = f"on {connect[0]}" if connect else "on the given session"
                raise MessageLinkError(f"no message link '{name}': no receiver answered {where}: "
                                       "has the subsystem that creates it started?")
            link.capacity = int(receivers[0]["capacity"])
            link.max_message_bytes = int(receivers[0]["max_message_bytes"])
            link._entities.append(link._session.declare_subscriber(f"{link.key}/credit/{link._id:x}", link._on_credit))
            link._publisher = link._session.declare_publisher(
                f"{link.key}/message",
                congestion_control=zenoh.CongestionControl.BLOCK,  # a message is never dropped by the network
                priority=getattr(zenoh.Priority, MESSAGE_PRIORITY),
                express=True,
            )
            link._entities.append(link._publisher)
            link._entities.append(link._publisher.declare_matching_listener(link._on_matching))
            give_up = time.monotonic() + ANSWER_TIMEOUT  # the receiver answered: its subscription is on its way
            while not link._publisher.matching_status.matching and time.monotonic() < give_up:
                time.sleep(0.001)
        except BaseException:
            link._close_session()
            raise
        return link

    def _missing(self, detail: str) -> PboError:
        return MessageLinkError(f"no message link '{self.name}': {detail}: has the subsystem that creates it started?")

    def _describe(self) -> dict:
        return {"format": MESSAGE_FORMAT, "capacity": self.capacity, "max_message_bytes": self.max_message_bytes,
                "pid": os.getpid(), "host": socket.gethostname()}

    # --- sending ------------------------------------------------------------------------------

    def send(self, body: Any, priority: int = 0, timeout: float | None = 0.0) -> None:
        """Send `body`; wait at most `timeout` s for room in this end's window (0: never, None: as long as it takes).

        Raises `LinkFullError` if the receiver still holds `capacity` of this end's messages.
        """
        sent_ns = time.monotonic_ns()
        raw = encode_message(self.name, priority, [self._id, sent_ns, priority, body], self.max_message_bytes)
        if self._session is None:
            raise MessageLinkError(f"message link '{self.name}' is closed")
        if self._publisher is not None and not self._publisher.matching_status.matching:
            raise MessageLinkError(f"message link '{self.name}' has no receiver connected: the message was not sent",
                                   hint="has the receiving subsystem stopped? send again once it is back")
        with self._room:
            if self._sent - self._consumed >= self.capacity:
                if timeout == 0 or not self._room.wait_for(lambda: self._sent - self._consumed < self.capacity, timeout):
                    raise LinkFullError(self.name, self.capacity, timeout or 0.0, bound="")
            self._sent += 1
            if self._publisher is None:  # the receiving end sends to itself
                self._enqueue(self._id, sent_ns, priority, body)
                return
        self._publisher.put(raw)

    def _on_credit(self, sample: Any) -> None:
        consumed = msgpack.unpackb(sample.payload.to_bytes())
        with self._room:
            if consumed > self._consumed:  # credits are cumulative: a late one changes nothing
                self._consumed = consumed
                self._room.notify_all()

    def _on_matching(self, status: Any) -> None:
        if not status.matching:  # the receiver left: what it held is gone, a new one counts from 0
            with self._room:
                self._sent = self._consumed = 0
                self._room.notify_all()

    # --- receiving ----------------------------------------------------------------------------

    def _on_message(self, sample: Any) -> None:
        try:
            sender, sent_ns, priority, body = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
        except (ValueError, TypeError, msgpack.UnpackException):
            with self._room:
                self._malformed += 1
                self._room.notify_all()
            return
        with self._room:
            self._enqueue(sender, sent_ns, priority, body)

    def _enqueue(self, sender: int, sent_ns: int, priority: int, body: Any) -> None:
        heapq.heappush(self._queue, (-priority, next(self._arrival), sender, sent_ns, body))
        self._room.notify_all()

    def receive(self, timeout: float | None = None) -> Message | None:
        """The waiting message of highest priority (oldest first within one), or None after `timeout` s (0: do not wait)."""
        if not self.owner:
            raise MessageLinkError(f"message link '{self.name}': only the end that created it receives; this one attached to send")
        with self._room:
            if not self._queue and timeout != 0:
                self._room.wait_for(lambda: self._queue or self._malformed, timeout)
            if self._malformed:
                count, self._malformed = self._malformed, 0
                raise MessageLinkError(f"message link '{self.name}' received {count} message(s) it cannot decode",
                                       hint="do both ends run the same version of pbo-runtime?")
            if not self._queue:
                return None
            negative_priority, _, sender, sent_ns, body = heapq.heappop(self._queue)
            consumed = self._consumed_by[sender] = self._consumed_by.get(sender, 0) + 1
            if sender == self._id:
                self._consumed = consumed
                self._room.notify_all()
        if sender != self._id and self._session is not None:
            self._session.put(f"{self.key}/credit/{sender:x}", msgpack.packb(consumed),
                              congestion_control=_zenoh().CongestionControl.BLOCK, priority=getattr(_zenoh().Priority, MESSAGE_PRIORITY),
                              express=True)
        return Message(body, -negative_priority, sent_ns)

    @property
    def waiting(self) -> int:
        """The receiver: messages in its queue. A sender: its messages the receiver has not taken yet."""
        with self._room:
            return len(self._queue) if self.owner else self._sent - self._consumed

    def close(self) -> None:
        """Undeclare this end and close its session (unless given one); a receiver's waiting messages are dropped."""
        if getattr(self, "_session", None) is None:
            return
        try:
            self._close_session()
        finally:
            self._session = None
            self._publisher = None

    def unlink(self) -> None:
        """Nothing to remove (kept for the shm link's interface)."""

    def __enter__(self) -> ZenohMessageLink:
        return self

    def __exit__(self, *_exc) -> None:
        self.close()


# --- choosing the transport -----------------------------------------------------------------------


def _transport(transport: str) -> str:
    if transport not in TRANSPORTS:
        raise LinkError(f"transport must be one of {', '.join(TRANSPORTS)}, got: {transport!r}")
    return transport


def _no_zenoh_options(name: str, port: int | None, session: Any) -> None:
    given = [what for what, value in (("port", port), ("session", session)) if value is not None]
    if given:
        raise LinkError(f"link '{name}' uses transport 'shm', which takes no {' or '.join(given)} (those are for transport 'zenoh')")


def open_link(transport: str, name: str, layout: LinkLayout, role: Role | str | None = None, *, create: bool,
              port: int | None = None, host: str = LOOPBACK, wait: float | None = DEFAULT_WAIT,
              session: Any = None) -> TripleBuffer | ZenohLink:
    """A periodic link's end over `transport` ('shm' or 'zenoh'); `create`: make it (shm) or listen (zenoh)."""
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
    if _transport(transport) == "shm":
        _no_zenoh_options(name, port, session)
        return MessageLink.create(name, capacity, max_message_bytes) if create else MessageLink.attach(name)
    if create:
        return ZenohMessageLink.create(name, capacity, max_message_bytes, port=port, host=host, session=session)
    return ZenohMessageLink.attach(name, port=port, host=host, session=session, wait=wait)


def _spec_endpoint(spec: Mapping[str, Any]) -> tuple[str, int]:
    """(host, port) of the spec the application runner hands down (`links.ends`), or LinkError."""
    endpoint = parse_endpoint(spec.get("endpoint", ""))
    if endpoint is None or "key" not in spec:
        raise LinkError(f"a zenoh link's spec needs 'key' and 'endpoint' ('tcp/<host>:<port>'), got: {dict(spec)!r}")
    return endpoint


def open_periodic(spec: Mapping[str, Any], layout: LinkLayout, role: Role | str) -> ZenohLink:
    """One end of an application's zenoh link from the spec the application runner hands down (`links.ends`).

    `spec`: {"key": "pbo/<app>/...", "endpoint": "tcp/<host>:<port>", "wait": seconds (optional)}.
    As the runner arranges it, the sender listens on the endpoint and the reader connects to it.
    The reader does not wait for the sender by default (its subsystem may start first, on another
    machine): it connects whenever the sender's end listens, and reads NONE until then.
    """
    host, port = _spec_endpoint(spec)
    if _role(role) is Role.SENDER:
        return ZenohLink.create(spec["key"], layout, Role.SENDER, port=port, host=host)
    return ZenohLink.attach(spec["key"], layout, role, port=port, host=host, wait=spec.get("wait", None))


def open_aperiodic(spec: Mapping[str, Any], role: str) -> ZenohMessageLink:
    """One end of an application's zenoh message link: the server listens on the spec's endpoint, the sender connects."""
    host, port = _spec_endpoint(spec)
    if role == "server":
        return ZenohMessageLink.create(spec["key"], int(spec.get("capacity") or SYSTEM_CAPACITY), port=port, host=host)
    return ZenohMessageLink.attach(spec["key"], port=port, host=host, wait=spec.get("wait", DEFAULT_WAIT))
