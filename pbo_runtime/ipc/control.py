"""Operator commands to a running subsystem: a control queue the supervisor serves between ticks.

`pbo status`, `pbo on/off/clear`, `pbo switch`, `pbo job`, `pbo stop` run in another terminal.
They reach the supervisor (job control) through one 0600 POSIX message queue per run,
`/pbo.<subsystem>.<run id>.control`, which the supervisor creates with the run and polls
without blocking between its own ticks (`ControlServer.poll`, a few requests within a time
budget). RTPUs never see a request: whatever a command changes, the supervisor does through
its own signals, so serving the operator cannot delay a cycle.

The protocol is msgpack on both sides:

    request  [command: str, reply_queue_name: str, arguments: dict]   -> the control queue
    reply    {"ok": True, ...} or {"ok": False, "error": "..."}         -> the reply queue
             (a refusal of what was asked, not of the run's state, adds "bad_request": True)

Each request brings its own reply queue, created 0600 by the client and named in the run's
namespace, `/pbo.<subsystem>.<run id>.reply-<client pid>-<nonce>`; the server answers only to
names of that form, so a request can never make the supervisor write into another queue of the
run (an RTPU's signal queue, the event queue). A reply queue lives for one request: the client
creates it just before sending and unlinks it in a `finally`, whether the answer came, timed
out, or the client was interrupted. (It cannot be found later by listing: /dev/mqueue may not
be mounted. Only a client killed by SIGKILL inside `request` leaves one; it holds one message
slot and goes away with a reboot or `rm /dev/mqueue/pbo.*` where that is mounted.) A reply
that finds its queue gone (the client gave up) is dropped.

`find_live_run` is how every operator tool finds the run it talks to without the YAML file:
the table segment `/dev/shm/pbo.<subsystem>.<pid>-<nonce>.table`, ours and 0600, whose supervisor
pid is alive (`ipc.runs`); `--subsystem` and `--run ID` pick one when several are.
The verbs, their arguments and replies are declared in `supervisor.commands`.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable
from typing import Any

import msgpack
import posix_ipc

from pbo_runtime.errors import PboError
from pbo_runtime.ipc import limits, messages, runs, shm

# Requests are small (a command, a name, at most a job's object values) and each client waits for
# its answer: a short queue of 4 KiB messages keeps the run's share of the per-user queue memory
# (RLIMIT_MSGQUEUE) small. It holds a poll and a half (MAX_REQUESTS_PER_POLL); a client that finds
# it full waits its timeout for the supervisor to serve.
REQUEST_BYTES = min(4096, messages.MESSAGE_BYTES)
REQUEST_SLOTS = min(6, messages.MAX_MESSAGES)
REPLY_BYTES = messages.MESSAGE_BYTES
MAX_REQUESTS_PER_POLL = 4

Handler = Callable[[str, dict[str, Any]], dict[str, Any]]


class CommandRefused(PboError):
    """The supervisor answered, and said no (the reply's `error` is the message)."""


class BadRequest(CommandRefused):
    """A request refused for what it asks, not for the run's state: no such task, values that are
    not finite numbers, an event for a periodic task, an unknown argument. The operator's input is
    wrong (the CLI exits 1, as for any bad argument); the reply carries `"bad_request": True`."""


def control_queue_name(subsystem: str, run_id: str) -> str:
    return shm.object_name(subsystem, run_id, "control")


def control_queue_size(subsystem: str, run_id: str) -> limits.QueueSize:
    return limits.QueueSize(control_queue_name(subsystem, run_id), REQUEST_SLOTS, REQUEST_BYTES)


def reply_queue_prefix(subsystem: str, run_id: str) -> str:
    """Every reply queue of a run starts with this; the server answers to no other name."""
    return shm.object_name(subsystem, run_id, "reply-")


# --- finding the run ------------------------------------------------------------------------


def live_runs() -> list[tuple[str, str, str]]:
    """(subsystem, run id, table name) of every live run of this user (`ipc.runs.live_runs`)."""
    return [(run.subsystem, run.run_id, run.table) for run in runs.live_runs()]


def find_live_run(subsystem: str | None = None, run: str | None = None) -> tuple[str, str, str]:
    """(subsystem, run id, table name) of the one live run meant; PboError if there is not exactly one.

    `run` is a run id or a unique prefix of one (`pbo runs` lists them); see `ipc.runs.find_run`.
    """
    found = runs.find_run(subsystem, run)
    return found.subsystem, found.run_id, found.table


# --- the supervisor's side ------------------------------------------------------------------


class ControlServer:
    """The control queue of one run, created by the supervisor and served between its ticks."""

    def __init__(self, subsystem: str, run_id: str) -> None:
        self.subsystem = subsystem
        self.run_id = run_id
        self.name = control_queue_name(subsystem, run_id)
        self._reply_prefix = reply_queue_prefix(subsystem, run_id)
        self._mq: posix_ipc.MessageQueue | None = posix_ipc.MessageQueue(
            self.name, posix_ipc.O_CREX, mode=0o600, max_messages=REQUEST_SLOTS, max_message_size=REQUEST_BYTES
        )
        self.size = limits.QueueSize(self.name, self._mq.max_messages, self._mq.max_message_size)
        self.served = 0
        self.dropped = 0

    def poll(self, handler: Handler, budget: float = 0.002) -> int:
        """Serve the requests waiting now (a few, within `budget` seconds); never blocks; returns how many."""
        if self._mq is None or not self._mq.current_messages:  # (most polls find none: no receive, no exception)
            return 0
        deadline = time.monotonic() + budget
        handled = 0
        while handled < MAX_REQUESTS_PER_POLL:
            try:
                raw, _priority = self._mq.receive(timeout=0)
            except (posix_ipc.BusyError, posix_ipc.SignalError):
                break  # nothing waiting, or a signal (Ctrl-C) the supervisor must see first
            handled += 1
            self._serve(raw, handler)
            if time.monotonic() >= deadline:
                break
        return handled

    def _serve(self, raw: bytes, handler: Handler) -> None:
        try:
            request = msgpack.unpackb(raw)
        except Exception:  # any garbage on the queue: nobody to answer
            self.dropped += 1
            return
        reply_to = request[1] if isinstance(request, list) and len(request) >= 2 else None
        if not isinstance(reply_to, str) or not reply_to.startswith(self._reply_prefix):
            self.dropped += 1  # no reply queue of this run named: answering could write anywhere
            return
        if len(request) != 3 or not isinstance(request[0], str) or not isinstance(request[2], dict):
            shape = ", ".join(type(item).__name__ for item in request)
            self._reply(reply_to, {"ok": False, "bad_request": True,
                                   "error": f"malformed request: expected [command, reply queue, arguments], "
                                            f"got a list of {len(request)} ({shape})"})
            return
        command, _, arguments = request
        self._reply(reply_to, answer(handler, command, arguments), command)

    def _reply(self, name: str, reply: dict[str, Any], command: str = "") -> None:
        try:
            raw = msgpack.packb(reply, default=plain)
        except (TypeError, ValueError, OverflowError) as exc:
            raw = msgpack.packb({"ok": False, "error": f"the reply to '{command}' cannot be encoded: {exc}"})
        if len(raw) > REPLY_BYTES:
            raw = msgpack.packb({"ok": False, "error": f"the reply to '{command}' has {len(raw)} bytes, "
                                                       f"more than a message holds ({REPLY_BYTES})"})
        try:
            queue = posix_ipc.MessageQueue(name)  # never created here: a queue that is gone stays gone
        except (posix_ipc.ExistentialError, posix_ipc.PermissionsError, ValueError, OSError):
            self.dropped += 1
            return
        try:
            queue.send(raw, timeout=0)  # never wait on a client
            self.served += 1
        except (posix_ipc.BusyError, posix_ipc.SignalError, ValueError, OSError):
            self.dropped += 1
        finally:
            queue.close()

    def close(self) -> None:
        """Close and unlink the queue (idempotent)."""
        if self._mq is None:
            return
        with contextlib.suppress(posix_ipc.ExistentialError):
            self._mq.close()
        self._mq = None
        shm.unlink_quietly("mq", self.name)

    def __enter__(self) -> ControlServer:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


def answer(handler: Handler, command: str, arguments: dict[str, Any]) -> dict[str, Any]:
    """The reply to one request as the supervisor sends it: `{"ok": True, ...}`, or the refusal.

    Never raises: a handler's refusal (PboError, ValueError, KeyError) becomes its message, a
    BadRequest adds `"bad_request": True`, and anything else is an internal error of the supervisor.
    """
    try:
        reply = handler(command, arguments)
        if not isinstance(reply, dict):
            raise TypeError(f"the handler returned {type(reply).__name__}, not a dict")
        return {"ok": True, **reply}
    except BadRequest as exc:
        return {"ok": False, "error": str(exc), "bad_request": True}
    except KeyError as exc:
        return {"ok": False, "error": str(exc.args[0]) if len(exc.args) == 1 else str(exc)}
    except (PboError, ValueError) as exc:
        return {"ok": False, "error": str(exc)}
    except Exception as exc:  # an operator's request must never bring the run down
        return {"ok": False, "error": f"internal error in the supervisor serving '{command}' "
                                      f"(please report this): {type(exc).__name__}: {exc}"}


def plain(value: Any) -> Any:
    """numpy scalars and arrays in a handler's reply travel as Python numbers and lists."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, (set, frozenset, tuple)):
        return list(value)
    raise TypeError(f"cannot send a {type(value).__name__}")


# --- the operator's side --------------------------------------------------------------------


class ControlClient:
    """Sends operator commands to the supervisor of one live run and waits for each answer."""

    def __init__(self, subsystem: str, run_id: str) -> None:
        self.subsystem = subsystem
        self.run_id = run_id
        self.control_name = control_queue_name(subsystem, run_id)
        self.last_reply_queue = ""  # the name the last request used (gone once it returned)

    @classmethod
    def connect(cls, subsystem: str | None = None, run: str | None = None) -> ControlClient:
        """The client of the live run meant by `subsystem` and `run` (a run id's prefix), or of the only one."""
        sub, run_id, _table = find_live_run(subsystem, run)
        return cls(sub, run_id)

    def request(self, command: str, arguments: dict[str, Any] | None = None, timeout: float = 2.0) -> dict[str, Any]:
        """Send one command and return the supervisor's reply dict (`ok` says whether it was done)."""
        deadline = time.monotonic() + timeout
        who = f"the supervisor of '{self.subsystem}'"
        try:
            control = posix_ipc.MessageQueue(self.control_name)
        except posix_ipc.ExistentialError:
            raise PboError(f"{who} (run {self.run_id}) has no control queue: it is still starting, "
                           f"stopping, or does not take commands") from None
        reply_name = f"{reply_queue_prefix(self.subsystem, self.run_id)}{os.getpid()}-{os.urandom(4).hex()}"
        self.last_reply_queue = reply_name
        replies: posix_ipc.MessageQueue | None = None
        try:
            try:
                replies = posix_ipc.MessageQueue(reply_name, posix_ipc.O_CREX, mode=0o600, max_messages=1,
                                                 max_message_size=REPLY_BYTES)
            except (posix_ipc.Error, OSError, ValueError) as exc:
                doing = f"creating a reply queue for '{command}'"
                reply_queue = limits.QueueSize(reply_name, 1, REPLY_BYTES)
                raise limits.explain(exc, doing, [reply_queue]) or PboError(f"{doing}: {exc}") from None
            raw = msgpack.packb([command, reply_name, dict(arguments or {})], default=plain)
            if len(raw) > REQUEST_BYTES:
                raise PboError(
                    f"the request '{command}' has {len(raw)} bytes, more than the control queue takes ({REQUEST_BYTES})"
                )
            try:
                control.send(raw, timeout=max(deadline - time.monotonic(), 0.0))
            except posix_ipc.BusyError:
                raise PboError(f"the control queue of '{self.subsystem}' stayed full for {timeout:g} s: "
                               f"{who} is not serving commands") from None
            answer = self._await_reply(replies, deadline)
            if answer is None:
                raise PboError(f"{who} did not answer within {timeout:g} s")
        finally:
            control.close()
            if replies is not None:
                replies.close()
                shm.unlink_quietly("mq", reply_name)
        try:
            reply = msgpack.unpackb(answer, strict_map_key=False)
        except Exception as exc:
            raise PboError(f"{who} sent a reply that is not msgpack: {exc}") from None
        if not isinstance(reply, dict) or "ok" not in reply:
            raise PboError(f"{who} sent a malformed reply to '{command}': {reply!r:.200}")
        return reply

    def call(self, command: str, arguments: dict[str, Any] | None = None, timeout: float = 2.0) -> dict[str, Any]:
        """`request`, raising CommandRefused with the supervisor's message when it said no."""
        reply = self.request(command, arguments, timeout)
        if not reply["ok"]:
            refusal = BadRequest if reply.get("bad_request") else CommandRefused
            raise refusal(f"'{self.subsystem}' refused '{command}': {reply.get('error') or 'no reason given'}")
        return reply

    @staticmethod
    def _await_reply(replies: posix_ipc.MessageQueue, deadline: float) -> bytes | None:
        raw: bytes
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            try:
                raw, _priority = replies.receive(timeout=remaining)
                return raw
            except posix_ipc.BusyError:
                return None
            except posix_ipc.SignalError:
                continue  # a signal whose handler did not raise: keep waiting for the rest of the time
