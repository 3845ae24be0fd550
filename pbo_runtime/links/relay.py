"""Wake an aperiodic server task when a message arrives from another subsystem (TR §5.1).

The executive waits in one place, a timed receive on its RTPU's signal queue, so signals and
timers share one wait (rtpu/_executive.py). A message link is another queue (or a Zenoh
subscription), so a relay thread blocks on the link and forwards each message to that signal
queue as `["message", task, [body, sent_ns]]`; the executive then releases the server as it does
for an operator's event, at most once per min_interarrival, its payload in `self.event`. On a
link whose blocked `receive()` a close wakes (`wakes_on_close`: zenoh's), the relay blocks without
a timeout, so it wakes only for a message; on a POSIX queue it looks at its stop flag every POLL.

On the simulated clock no thread forwards: the RTPU calls `pump` at the start of each lockstep
step, so a message is served at the first step after it was sent, whatever the scheduler did
(`clock.application_lockstep` orders the subsystems' steps).

The relay never touches the table or the task: the server's cycle runs on the executive's thread,
with the usual transfers. Back-pressure is bounded at every step: the signal queue holds
fs.mqueue.msg_max messages, the executive a server's EVENTS_QUEUED (more are counted as dropped),
and while the relay waits for room the link's own queue fills, so its sender gets LinkFullError
instead of a silent loss.
"""

from __future__ import annotations

import threading
from typing import Any

from pbo_runtime.ipc import messages
from pbo_runtime.objects.helper_threads import below_the_cycle

POLL = 0.1  # seconds the relay blocks on the link before it looks at its stop flag


class MessageRelay:
    """Forwards the messages of `link` (a receiving end) to RTPU signal queue `signal_queue` (its name, or an
    end of it opened for the relay, which closes it) for `task`."""

    def __init__(self, link: Any, signal_queue: str | messages.Queue, task: str, threaded: bool = True) -> None:
        self.link = link
        self.task = task
        self.forwarded = 0
        self.closed = False
        self._signals = messages.Queue(signal_queue) if isinstance(signal_queue, str) else signal_queue
        self._stop = threading.Event()
        self._held: list[Any] | None = None  # pump: a message taken from the link that the signal queue had no room for
        self._thread: threading.Thread | None = None
        self._wakes = bool(getattr(link, "wakes_on_close", False))  # closing the link ends a receive without timeout
        # `close` joins the forwarding thread (up to POLL): a killed task's RTPU closes it in its
        # background thread, not between two cycles (`task.lifecycle`); the simulated clock's relay
        # has no thread and closes at once, in step with the ticks.
        self.closes_slowly = threaded
        if threaded:
            self._thread = threading.Thread(target=self._forward, name=f"relay-{task}", daemon=True)
            self._thread.start()

    def pump(self) -> None:
        """Forward every message the link holds now, without waiting (the simulated clock's relay)."""
        while not self.closed:
            if self._held is None:
                message = self.link.receive(timeout=0.0)
                if message is None:
                    return
                self._held = [message.body, message.sent_ns]
            if not self._signals.try_send("message", self.task, self._held, timeout=0.0):
                return  # the signal queue is full: the rest waits for the next step, in the link's own queue
            self._held = None
            self.forwarded += 1

    def _forward(self) -> None:
        below_the_cycle()  # it shares the executive's GIL
        link, stop, signals = self.link, self._stop, self._signals
        wait = None if self._wakes else POLL
        while not stop.is_set():
            try:
                message = link.receive(timeout=wait)
            except Exception:  # the link closed under us: the task is being killed
                return
            if message is None:
                continue
            payload = [message.body, message.sent_ns]
            while not signals.try_send("message", self.task, payload, timeout=POLL):
                if stop.is_set():
                    return
            self.forwarded += 1

    def close(self) -> None:
        """Stop forwarding, then close the link's end (the task is killed)."""
        self._stop.set()
        self.closed = True
        if self._wakes:
            self.link.close()  # first: it wakes the thread blocked in receive()
        if self._thread is not None:
            self._thread.join(timeout=5 * POLL)
        self._signals.close()
        self.link.close()  # (twice is harmless)
