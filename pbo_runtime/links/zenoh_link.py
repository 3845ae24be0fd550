"""The periodic link over eclipse-zenoh: the same API and semantics as `links.triple_buffer.TripleBuffer`.

When an application outgrows one machine its links run over Zenoh, chosen per link in the YAML
(`transport: shm | zenoh`). The sender puts each item as one express `put` and never waits; the
reader keeps the newest complete item, delivered by a one-sample ring it drains at each read
(`delivery="ring"`) or by a callback (`"callback"`). Counters never go back, across a sender's
restart too, and ages are judged on the reader's clock. The session is `links.zenoh_session`'s,
the message link `links.zenoh_message_link`; `open_periodic` opens an end from the spec the
application runner hands down (`links.ends`). What differs from shared memory, and why:
docs/subsystems.md, "Links over Zenoh".
"""

from __future__ import annotations

import os
import socket
import struct
import threading
import time
from typing import Any

import numpy as np

from pbo_runtime.links.run_link import RunLink
from pbo_runtime.links.triple_buffer import (
    Freshness,
    LinkError,
    LinkLayout,
    LinkLayoutError,
    LinkStatistics,
    ReaderTally,
    Role,
    _role,
)
from pbo_runtime.links.zenoh_session import (
    DEFAULT_WAIT,
    LOOPBACK,
    SessionEnd,
    endpoints,
    key_expression,
    spec_endpoint,
    zenoh_module,
)

ITEM_FORMAT = 0x5042_4F5F_5A4E_0001  # "PBO_ZN", wire format 1: the first word of every item
ITEM_HEADER = struct.Struct("<qqqqqq")  # format, layout hash, sender epoch, counter, stamp ns, reserved
DELIVERIES = ("ring", "callback")  # how a reader gets items from zenoh (see the module's docstring)
PERIODIC_PRIORITY = "REAL_TIME"  # zenoh.Priority of periodic items: the highest data priority


class ZenohLink(SessionEnd, ReaderTally):
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
        payload = np.frombuffer(self._wire, dtype=layout.dtype, count=layout.size, offset=ITEM_HEADER.size)
        self._payload = payload.reshape(layout.shape)
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
        listen, connect = endpoints(name, port, host, session, listening=True)
        return cls._open(name, layout, role, True, session, listen, connect, 0, delivery)

    @classmethod
    def attach(cls, name: str, layout: LinkLayout, role: Role | str | None = None, *, port: int | None = None,
               host: str = LOOPBACK, session: Any = None, wait: float | None = DEFAULT_WAIT,
               delivery: str = "ring") -> ZenohLink:
        """Connect to the creating end's `tcp/<host>:<port>` (or use `session`), trying for up to `wait` s.

        `wait`: 0 one try; None: do not wait, connect in the background whenever the creating end
        appears (a reader then reads NONE until the first item comes).
        """
        listen, connect = endpoints(name, port, host, session, listening=False)
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

    def _forget(self) -> None:
        self._publisher = self._ring = None
        self._set_role(None)

    def unlink(self) -> None:
        """Nothing to remove: a zenoh link leaves no name behind (kept for the shm link's interface)."""

    def __enter__(self) -> ZenohLink:
        return self

    def __exit__(self, *_exc: object) -> None:
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
        zenoh = zenoh_module()
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

    def _describe(self) -> dict[str, Any]:
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
        return (f"link '{self.name}' carries {found}, this process expects {self.layout.description}: "
                "do both ends declare the same payload?")

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

    def write(self, value: Any, stamp_ns: int | None = None) -> int:
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
            view = np.frombuffer(raw, dtype=self.layout.dtype, count=self.layout.size, offset=ITEM_HEADER.size)
            self._view = view.reshape(self.layout.shape)
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
            return (f"link '{self.name}' received an item that is not a pbo zenoh item of format {ITEM_FORMAT & 0xFFFF} "
                    f"({size} bytes)")
        found: list[Any] = [
            o.get("layout") for o in self._other_ends(f"{self.key}/end/sender") if o.get("layout_hash") == layout_hash
        ]
        return self._mismatch(found[0] if found else f"items of {size - ITEM_HEADER.size} bytes of another payload")

    def statistics(self) -> LinkStatistics:
        return LinkStatistics(writes=self._writes, new=self._new, reused=self._reused, lost=self._lost, empty=self._empty,
                              contended=self._contended, lock_recoveries=0)


def open_periodic(spec: RunLink, layout: LinkLayout, role: Role | str) -> ZenohLink:
    """One end of an application's zenoh link from the spec the application runner hands down (`links.ends`).

    `spec`: its key ("pbo/<app>/..."), endpoint ("tcp/<host>:<port>") and, optionally, wait (seconds).
    As the runner arranges it, the sender listens on the endpoint and the reader connects to it.
    The reader does not wait for the sender by default (its subsystem may start first, on another
    machine): it connects whenever the sender's end listens, and reads NONE until then.
    """
    host, port = spec_endpoint(spec)
    if _role(role) is Role.SENDER:
        return ZenohLink.create(spec.key, layout, Role.SENDER, port=port, host=host)
    return ZenohLink.attach(spec.key, layout, role, port=port, host=host, wait=spec.wait)
