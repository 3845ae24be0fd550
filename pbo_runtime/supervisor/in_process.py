"""Children hosted in the supervisor's own process (`pbo run --clock sim --one-process`).

The plant and each RTPU are built by the code their processes run (found by module name, as
the fork server finds them: the runtime never imports `rtpu`), and take their turns when the
simulated clock's ring calls them (`clock.local_ring`). `InProcessChild` stands where a child
process stands in `Children`: it answers `poll`, `send_signal`, `wait` and `kill` as the
process would, so stopping a run, its summary and its report take the path they always take.
"""

from __future__ import annotations

import importlib
import os
import signal
import sys
import threading
import traceback
from collections.abc import Callable
from typing import Any, Protocol

from pbo_runtime.config.model import Subsystem
from pbo_runtime.ipc import limits, messages
from pbo_runtime.supervisor.cleanup import unlink_run

PLANT_MODULE = "pbo_runtime.supervisor.plant_host"
RTPU_IN_PROCESS = "rtpu.in_process"  # what hosts an RTPU here, for `python -m rtpu`


class Hosted(Protocol):
    """A participant hosted here: its turn, its exit status, and its end on SIGTERM."""

    def step(self, new_tick: bool) -> None: ...
    def poll(self) -> int | None: ...
    def terminate(self) -> None: ...


class NeverStarted:
    """A participant whose start failed: no turns, ended with exit status 1."""

    def step(self, new_tick: bool) -> None:
        pass

    def poll(self) -> int | None:
        return 1

    def terminate(self) -> None:
        pass


class InProcessChild:
    """A participant hosted in this process, seen as a child process (`Children`)."""

    def __init__(self, hosted: Hosted) -> None:
        self.hosted = hosted
        self.pid = os.getpid()

    @classmethod
    def start(cls, arguments: list[str], subsystem: Subsystem, events: messages.Queue,
              join: Callable[[Callable[[bool], None]], None], signals: messages.Queue | None = None) -> InProcessChild:
        """Host what `python ARGUMENTS` (`-m MODULE ...`) would run; it joins the ring through `join`. An
        RTPU reads its signals from another end of `signals`, job control's end of its queue."""
        module, argv = arguments[1], arguments[2:]
        hosted: Any
        try:
            if module == PLANT_MODULE:
                hosted = importlib.import_module(PLANT_MODULE).in_process(argv, events)
            else:
                hosted = importlib.import_module(RTPU_IN_PROCESS).start(argv, subsystem, events, signals)
        except Exception as exc:  # as its process would: reported, and it has ended (exit status 1)
            role = "plant" if module == PLANT_MODULE else argv[argv.index("--rtpu") + 1]
            limit = limits.explain(exc, f"{role} starting")
            events.report(role, messages.Crashed(str(limit), "") if limit is not None
                          else messages.Crashed(f"{type(exc).__name__}: {exc}", traceback.format_exc()))
            hosted = NeverStarted()
        join(hosted.step)
        return cls(hosted)

    def poll(self) -> int | None:
        return self.hosted.poll()

    def send_signal(self, signum: int) -> None:
        if signum in (signal.SIGTERM, signal.SIGKILL, signal.SIGINT):
            self.hosted.terminate()

    def wait(self, timeout: float | None = None) -> int:
        self.hosted.terminate()  # (only ever waited for once told to end)
        code = self.hosted.poll()
        return 0 if code is None else code

    def kill(self) -> None:
        self.hosted.terminate()


class SecondStop:
    """Two stop signals (Ctrl-C, SIGTERM) end the one process at once, whatever its main thread is doing.

    A cycle that never returns holds the main thread, where Python runs signal handlers, and a
    signal the kernel gives another thread does not even wake it. The C handler still writes each
    signal's number to the wake-up pipe, which a thread of this class reads.
    """

    def __init__(self, on_second: Callable[[], None]) -> None:
        self._read, self._write = os.pipe()
        os.set_blocking(self._write, False)
        self._previous = signal.set_wakeup_fd(self._write, warn_on_full_buffer=False)
        self._on_second = on_second
        threading.Thread(target=self._watch, name="pbo-second-stop", daemon=True).start()

    def _watch(self) -> None:
        stops = 0
        try:
            while data := os.read(self._read, 64):
                stops += sum(1 for signum in data if signum in (signal.SIGINT, signal.SIGTERM))
                if stops >= 2:
                    self._on_second()
        except OSError:  # closed: the run is over
            pass

    def close(self) -> None:
        signal.set_wakeup_fd(self._previous)
        os.close(self._write)  # the watch reads the end of the pipe and returns


def end_at_once(manifest: list[str], subsystem: str, run_id: str) -> None:
    """One process, told twice to stop: a participant hosted here may be in a cycle that never returns,
    and nothing else would end the run. Its objects are removed; what the data logs had not written
    yet is lost (they are written in chunks); the process exits 2."""
    sys.stderr.write("error: stopped at once (told twice to stop, in one process): the last data of the logs may be lost\n")
    unlink_run(manifest, subsystem, run_id)
    os._exit(2)
