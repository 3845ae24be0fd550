"""The special-purpose processor driver (TR §4.6.3): download work to an SPP, call it, never wait on it.

A special-purpose processor (the report's floating-point accelerators, image processors) is
emulated as the RTPUs are: one OS process of its own (`drivers.spp.processor`). This driver
object is the task's hardware-independent interface to it, with the report's generic components:

- initialise: opening the device (the task's `init`) starts the processor and maps the memory
  it shares with it (a 0600 segment and a wake-up semaphore named after the run);
- download: `download(routine, data, **options)` sends a routine's name (the subroutine name the
  processor translates into its own code) and its data, e.g. the arm's ARM and EE tables; the
  processor builds it and answers the sizes of its inputs and outputs (or why it cannot);
- call and transfer: `call(inputs, outputs)`, the per-cycle remote procedure call, posts this
  cycle's inputs and copies the newest result out. It allocates nothing and never waits: the
  result answers an earlier call (the processor runs beside the task, as the report's SPPs run
  beside their RTPU), and the call returns its age in calls (1: the previous call's inputs);
- synchronise: `call_and_wait(inputs, outputs, timeout)` waits for the answer to these very
  inputs, for `init` and `on` (never a cycle).

A result older than the module allows is the module's to judge: `fault` says "" while the
processor lives, and why not once it died (looked at only when a result is late, so a live
processor costs nothing). Closing the device stops the processor and unlinks what it shared;
the processor unlinks them itself if the task's process dies first, and the supervisor removes
whatever a run left under its name. `figures()` are the processor's own: work items done,
service time p50/p99/max, requests it never took (missed), and calls answered late.

options: `memory` (float64 numbers for the inputs, and again for the outputs; default 4096),
`download_bytes` (the download area, default 262144), `start_timeout` (s, default 60: the
processor imports numpy and Pinocchio on a machine that may be busy).
"""

from __future__ import annotations

import contextlib
import math
import os
import select
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Mapping
from typing import Any

import msgpack
import numpy as np
import posix_ipc

from drivers.spp.segment import MAGIC, RING, State, W, layout, views
from pbo_runtime import DeviceDriver, create_segment, process_below_the_cycle, sleep_while_cycling, unlink_quietly

_OPTIONS = ("memory", "download_bytes", "start_timeout")
_DEFAULTS = {"memory": 4096, "download_bytes": 262144, "start_timeout": 60.0}
_MAX_MEMORY = 1 << 24  # the processor's memory and its downloads are allocated: a typo must not take the machine's
_MAX_DOWNLOAD_BYTES = 64 << 20
_POLL = 0.001  # seconds between looks while init or on waits for the processor
_STOP_TIMEOUT = 2.0
_opened = 0  # processors this process started: part of their names
# the driver's counters (`_n`): the last request posted, the one the newest result answers, the
# RESULT_SEQ of that result, a result's number while it is read, calls, late calls
_SENT, _ANSWERED, _SEEN, _NUMBER, _CALLS, _LATE = range(6)
_COUNTERS = 6


class ProcessorError(RuntimeError):
    """The processor cannot start, take a download or answer in time (raised in init or on, never in a cycle)."""


def _check_options(options: Mapping[str, Any]) -> dict[str, Any]:
    unknown = sorted(set(options) - set(_OPTIONS))
    if unknown:
        raise ValueError(f"unknown spp option(s) {unknown}; valid options: {', '.join(_OPTIONS)}")
    checked = {**_DEFAULTS, **options}
    for name, most in (("memory", _MAX_MEMORY), ("download_bytes", _MAX_DOWNLOAD_BYTES)):
        value = checked[name]
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= most:
            raise ValueError(f"spp option {name} must be a whole number in [1, {most}], got: {value!r}")
    timeout = checked["start_timeout"]
    if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not (math.isfinite(timeout) and 0 < timeout <= 3600):
        raise ValueError(f"spp option start_timeout must be a number of seconds in (0, 3600], got: {timeout!r}")
    return checked


def _names(registers: str) -> tuple[str, str]:
    """(segment, semaphore) of a new processor: under the run's prefix, so the run's cleanup finds them."""
    global _opened
    _opened += 1
    parts = registers.split(".")
    prefix = ".".join(parts[:-1]) if len(parts) >= 4 else registers  # /pbo.<subsystem>.<run id>.plant -> its run
    base = f"{prefix}.spp{os.getpid()}-{_opened}"
    return base, f"{base}.wake"


class SpecialPurposeProcessor(DeviceDriver):
    """An emulated special-purpose processor: download a routine, then call it every cycle without waiting."""

    KIND = "spp"
    OPTIONS = _OPTIONS

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> None:
        """ValueError for an unknown or bad option (the checker reports it as E607)."""
        _check_options(options)

    def __init__(self, registers: str, options: Mapping[str, Any], **_: Any) -> None:
        super().__init__(registers, options)
        checked = _check_options(self.options)
        self.memory, self.download_bytes = int(checked["memory"]), int(checked["download_bytes"])
        self.segment, self.semaphore_name = _names(registers)
        self.routine = ""
        self.process: subprocess.Popen[bytes] | None = None
        self.fault = ""
        self._taken: tuple[np.ndarray, tuple[int, int, float, int, int]] | None = None  # `_take_figures`
        self._scheduler = ""  # the processor's scheduling policy, as `_take_figures` last saw it
        # the driver's counters, in an array: updated in place, so a call boxes no new integer to keep
        self._n = np.zeros(_COUNTERS, dtype=np.int64)
        self._mapping = None
        self._wake = None
        try:
            self._shm, self._mapping = create_segment(self.segment, layout(self.memory, self.download_bytes)["total"][1])
            self._wake = posix_ipc.Semaphore(self.semaphore_name, posix_ipc.O_CREX, mode=0o600, initial_value=0)
            self._words, self._ring, self._request, self._result, self._download = views(
                self._mapping, self.memory, self.download_bytes)
            self._words[W.MAGIC] = MAGIC
            self.process = subprocess.Popen(
                [sys.executable, "-m", "drivers.spp.processor", self.segment, "--semaphore", self.semaphore_name,
                 "--memory", str(self.memory), "--download-bytes", str(self.download_bytes), "--parent", str(os.getpid())],
                stdin=subprocess.DEVNULL, start_new_session=True)
            self._await(lambda: self._words[W.STATE] != State.STARTING, float(checked["start_timeout"]), "start")
            self.pid = int(self._words[W.PID])
        except BaseException:
            self.close()
            raise

    # --- download -------------------------------------------------------------------------------

    def download(self, routine: str, data: Mapping[str, np.ndarray] | None = None, timeout: float = 30.0,
                 **options: Any) -> tuple[int, int]:
        """Load `routine` with its `data` (name -> array) and options; (input size, output size) in float64s.

        For `init`: it waits (up to `timeout` s) for the processor to build the routine, and raises
        ProcessorError with the processor's reason if it cannot.
        """
        arrays = {name: [list(np.shape(value)), np.asarray(value, dtype=np.float64).ravel().tolist()]
                  for name, value in (data or {}).items()}
        blob = msgpack.packb({"routine": routine, "arrays": arrays, "options": options})
        if len(blob) > self.download_bytes:
            raise ProcessorError(f"the download of routine {routine!r} takes {len(blob)} bytes; the processor's download "
                                 f"area has {self.download_bytes}: raise the device's option download_bytes")
        words = self._words
        self._download[:len(blob)] = np.frombuffer(blob, dtype=np.uint8)
        words[W.DOWNLOAD_BYTES] = len(blob)
        seq = int(words[W.DOWNLOAD_SEQ]) + 1
        words[W.DOWNLOAD_SEQ] = seq
        self._post()
        self._await(lambda: words[W.DOWNLOAD_ACK] == seq, timeout, f"load routine {routine!r}")
        if words[W.STATE] != State.LOADED:
            reason = self._download[:int(words[W.ANSWER_BYTES])].tobytes().decode(errors="replace")
            raise ProcessorError(f"the special-purpose processor could not load routine {routine!r}: {reason}")
        self.routine = routine
        self.in_size, self.out_size = int(words[W.IN_SIZE]), int(words[W.OUT_SIZE])
        self._inputs = self._request[:self.in_size]
        self._answer = self._result[:self.out_size]
        self._newest = np.zeros(self.out_size)  # the newest complete result
        self._taking = np.zeros(self.out_size)
        self._n[:] = 0
        if self.process is not None:
            # Built, its imports done: from here it runs above every ordinary process (at SCHED_OTHER the
            # machine's other work, or a helper's start-up, could hold it off for tens of cycles), below
            # every executive. A restarted RTPU raises it again when it takes SCHED_FIFO itself.
            process_below_the_cycle(self.process.pid)
        return self.in_size, self.out_size

    # --- the per-cycle call ---------------------------------------------------------------------

    def call(self, inputs: np.ndarray, outputs: np.ndarray) -> int:
        """Post `inputs` (in_size float64s) and copy the newest result into `outputs` (out_size); return its age.

        The age is in calls: 1 when the result answers the previous call's inputs, 2 the one
        before, ...; 0 when no result has come yet (outputs untouched). Real-time safe: no
        allocation, no waiting. When the result is late (age > 1), `fault` is looked at.
        """
        n = self._n
        self._take()
        answered = n[_ANSWERED]
        if answered:
            np.copyto(outputs, self._newest)
        words = self._words
        n[_SENT] += 1
        words[W.REQUEST_SEQ] += 1  # odd: mid-write
        np.copyto(self._inputs, inputs)
        words[W.REQUEST_ID] = n[_SENT]
        words[W.REQUEST_SEQ] += 1
        self._post()
        n[_CALLS] += 1
        age = int(n[_SENT] - answered) if answered else 0
        if age > 1 or not answered:
            n[_LATE] += 1
            if not self.fault:
                self._look_for_death()
        return age

    def call_and_wait(self, inputs: np.ndarray, outputs: np.ndarray, timeout: float = 5.0) -> None:
        """The answer to these very inputs, waiting up to `timeout` s (for `init` and `on`, never a cycle)."""
        self.call(inputs, outputs)
        sent = int(self._n[_SENT])
        self._await(lambda: self._take() >= sent, timeout, f"answer a call of routine {self.routine!r}")
        np.copyto(outputs, self._newest)

    def _take(self) -> int:
        """Copy a result newer than the last taken, if one is complete; the request number it answers."""
        words, n = self._words, self._n
        seq = words[W.RESULT_SEQ]
        if seq != n[_SEEN] and not seq & 1:
            np.copyto(self._taking, self._answer)
            n[_NUMBER] = words[W.RESULT_ID]
            if words[W.RESULT_SEQ] == seq:
                self._newest, self._taking = self._taking, self._newest
                n[_ANSWERED] = n[_NUMBER]
                n[_SEEN] = seq
        return int(n[_ANSWERED])

    def _post(self) -> None:
        try:  # noqa: SIM105 - per call of a cycle: contextlib.suppress would allocate each time
            self._wake.release()  # type: ignore[union-attr]
        except posix_ipc.Error:  # the count is at its most: the processor has posts enough to wake on
            pass

    # --- faults and waits ----------------------------------------------------------------------

    def _look_for_death(self) -> None:
        process = self.process
        if process is None:
            return
        try:
            ended = os.waitid(os.P_PID, process.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
        except ChildProcessError:  # already reaped (Popen.poll): its return code says how
            ended = None
            if process.returncode is None:
                return
        if ended is None and process.returncode is None:
            return
        if ended is None:
            code = process.returncode
            how = f"killed by {signal.Signals(-code).name}" if code < 0 else f"exit status {code}"
            self.fault = f"the special-purpose processor (pid {process.pid}) died ({how})"
            return
        how = (f"killed by {signal.Signals(ended.si_status).name}" if ended.si_code in (os.CLD_KILLED, os.CLD_DUMPED)
               else f"exit status {ended.si_status}")
        self.fault = (f"the special-purpose processor (pid {process.pid}) died ({how}); its last result answers call "
                      f"{self._n[_ANSWERED]} of {self._n[_SENT]}")

    def await_death(self, within: float) -> str:
        """The fault if the processor is found dead within `within` s of its newest result, else "". For a
        task about to say the processor does not keep up, once, on its way to ERROR: a processor killed a
        moment ago may still be ending, and its death, not its lateness, is what the operator must read.
        Only what is left of `within` since that result is waited: on the real clock a task whose
        `max_age` cycles last that long finds its result too old no sooner, and does not wait in its
        cycle; on the simulated clock its cycles come faster than the processor's end."""
        process = self.process
        if self.fault or process is None:
            return self.fault
        newest = int(self._words[W.RESULT_NS]) / 1e9 if self._mapping is not None else 0.0
        if newest:
            within = max(0.0, newest + within - time.monotonic())
        try:
            pidfd = os.pidfd_open(process.pid) if within > 0 else -1
        except (AttributeError, OSError):
            pidfd = -1
        if pidfd >= 0:
            try:
                select.select([pidfd], [], [], within)
            finally:
                os.close(pidfd)
        self._look_for_death()
        return self.fault

    def _await(self, done: Callable[[], bool], timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        while not done():
            if self.process is not None and self.process.poll() is not None:
                code = self.process.returncode
                how = f"killed by {signal.Signals(-code).name}" if code < 0 else f"exit status {code}"
                raise ProcessorError(f"the special-purpose processor (pid {self.process.pid}) died ({how}) "
                                     f"before it could {what}")
            if time.monotonic() > deadline:
                raise ProcessorError(f"the special-purpose processor did not {what} within {timeout:g} s")
            sleep_while_cycling(_POLL)  # in a live spawn's init, the RTPU's other tasks go on cycling

    # --- figures and closing -------------------------------------------------------------------

    def figures(self) -> dict[str, Any]:
        """The processor's own timing: work items, service time p50/p99/max (s), misses, late calls."""
        if self._mapping is not None:
            self._take_figures()
        if self._taken is None:
            return {}
        service, (items, missed, service_max, calls, late) = self._taken

        def pct(q: float) -> float:
            return float(np.percentile(service, q)) / 1e9 if service.size else 0.0

        return {"processor": "spp", "routine": self.routine, "items": items, "missed": missed,
                "service_p50": pct(50), "service_p99": pct(99), "service_max": service_max,
                "calls": calls, "late_calls": late, "fault": self.fault, "scheduler": self._scheduler}

    def _take_figures(self) -> None:
        """Copy the counts and service times out of the shared memory; the percentiles wait for `figures()`."""
        words = self._words
        items = int(words[W.ITEMS])
        self._taken = (
            self._ring[: min(items, RING)].copy(),
            (items, int(words[W.MISSED]), int(words[W.SERVICE_NS_MAX]) / 1e9, int(self._n[_CALLS]), int(self._n[_LATE])),
        )
        self._scheduler = _scheduler(self.process) or self._scheduler

    def close(self) -> None:
        """Stop the processor and unlink what it shared (idempotent); `figures()` keeps their last values."""
        self.close_now()()

    def close_now(self) -> Callable[[], None]:
        """Unlink and unmap what the processor shares (the device may be opened again at once: a new
        processor has names of its own), keeping its figures; return the processor's stop (SIGTERM,
        its exit waited for up to `_STOP_TIMEOUT`, then SIGKILL), which a task's kill hands to its
        RTPU's background thread."""
        if self._mapping is not None and self.process is not None:
            if not self.fault:
                self._look_for_death()  # a processor that died under a task that no longer called it
            self._take_figures()
        process, self.process = self.process, None
        for name in ("_words", "_ring", "_request", "_result", "_download", "_inputs", "_answer"):
            self.__dict__.pop(name, None)
        unlink_quietly("shm", self.segment)
        unlink_quietly("sem", self.semaphore_name)
        wake, self._wake = self._wake, None
        if wake is not None:
            wake.close()
        mapping, self._mapping = self._mapping, None
        if mapping is not None:
            # a view of it outlives the driver (a caller kept one): the mapping goes with it
            with contextlib.suppress(BufferError):
                mapping.close()
        return lambda: _stop(process)


def _scheduler(process: subprocess.Popen[bytes] | None) -> str:
    """The processor's scheduling policy, for its figures: "SCHED_FIFO 1", "SCHED_OTHER"; "" once it ended."""
    if process is None:
        return ""
    try:
        policy = os.sched_getscheduler(process.pid) & ~os.SCHED_RESET_ON_FORK
        priority = os.sched_getparam(process.pid).sched_priority
    except OSError:
        return ""
    return f"SCHED_FIFO {priority}" if policy == os.SCHED_FIFO else "SCHED_OTHER"


def _stop(process: subprocess.Popen[bytes] | None) -> None:
    """Stop the processor and reap it; one that does not stop within `_STOP_TIMEOUT` is killed."""
    if process is None:
        return
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)
    try:
        process.wait(timeout=_STOP_TIMEOUT)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
