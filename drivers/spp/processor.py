"""`python -m drivers.spp.processor`: the emulated special-purpose processor, one OS process.

The driver starts it when a task opens the device and stops it when the task closes it. It maps
the segment and semaphore the driver made, then sleeps on the semaphore: each post is either a
download (build the routine named in it, answer with its sizes or why not) or a call (take the
newest request under its seqlock, run the routine, publish the result and the request's number
under the result's seqlock). It counts work items, requests it never took (misses) and keeps its
service times in a ring, all in the segment, where the driver reads them.

It dies with the process that started it (PR_SET_PDEATHSIG) and, on every way out (a stop, its
parent gone, an error), unlinks the segment and the semaphore: a driver that could not (its
process was killed) leaves nothing behind either.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import mmap
import os
import signal
import sys
import time
from types import FrameType

import msgpack
import numpy as np
import posix_ipc

from drivers.spp import routines
from drivers.spp.segment import MAGIC, RING, State, W, views
from pbo_runtime import attach_segment, unlink_quietly

WAKE_SLICE = 1.0  # seconds between looks at the parent while no work comes


class _Stop(BaseException):
    """SIGTERM, SIGINT or SIGHUP: leave the loop through the `finally` that unlinks."""


_stopping = ""


def _stop(signum: int, _frame: FrameType | None) -> None:
    """Raise once: a second signal (the parent's death signal after a SIGTERM) must not break into
    the `finally` that unlinks."""
    global _stopping
    if _stopping:
        return
    _stopping = signal.Signals(signum).name
    raise _Stop(_stopping)


def _die_with(parent: int) -> None:
    for signum in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(signum, _stop)
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None).prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
    if os.getppid() != parent:  # the parent died before the request took effect
        raise _Stop("parent gone")


def _own_processor() -> None:
    """Leave what the task's RTPU process handed down: its SCHED_FIFO priority and its CPU. The
    processor is another piece of hardware; here it must never take an RTPU's CPU from it. It
    starts (imports, builds its routine) at SCHED_OTHER; once it has loaded, its driver puts it
    just below every executive (`process_below_the_cycle`)."""
    with contextlib.suppress(OSError, AttributeError):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    with contextlib.suppress(OSError, AttributeError):
        os.sched_setaffinity(0, range(os.cpu_count() or 1))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m drivers.spp.processor")
    parser.add_argument("segment")
    parser.add_argument("--semaphore", required=True)
    parser.add_argument("--memory", type=int, required=True)
    parser.add_argument("--download-bytes", type=int, required=True)
    parser.add_argument("--parent", type=int, required=True)
    args = parser.parse_args(argv)
    mapping = semaphore = None
    try:
        _die_with(args.parent)
        _own_processor()
        mapping = attach_segment(args.segment)
        semaphore = posix_ipc.Semaphore(args.semaphore)
        serve(mapping, semaphore, args.memory, args.download_bytes, args.parent)
    except _Stop:
        return 0
    finally:
        unlink_quietly("shm", args.segment)
        unlink_quietly("sem", args.semaphore)
        if semaphore is not None:
            semaphore.close()
    return 0


def serve(mapping: mmap.mmap, semaphore: posix_ipc.Semaphore, memory: int, download_bytes: int, parent: int) -> None:
    words, ring, request, result, download = views(mapping, memory, download_bytes)
    if words[W.MAGIC] != MAGIC:
        raise SystemExit("not a special-purpose processor's segment")
    words[W.PID] = os.getpid()
    words[W.STATE] = State.READY
    routine = None
    inputs = outputs = np.zeros(0)
    taken = 0  # the last request taken
    while True:
        try:
            semaphore.acquire(WAKE_SLICE)
        except posix_ipc.BusyError:
            if os.getppid() != parent:
                return
            continue
        except posix_ipc.SignalError:  # a signal landed in the wait: posix_ipc swallowed what its handler raised
            if _stopping:
                raise _Stop(_stopping) from None
            continue
        if words[W.DOWNLOAD_SEQ] != words[W.DOWNLOAD_ACK]:
            routine = _download(words, download, memory)
            if routine is not None:
                inputs, outputs = np.zeros(routine.in_size), np.zeros(routine.out_size)
            taken = 0
            continue
        if routine is None:
            continue
        seq = words[W.REQUEST_SEQ]
        if seq & 1:
            continue  # mid-write: the driver posts again with its next call
        np.copyto(inputs, request[:routine.in_size])
        number = int(words[W.REQUEST_ID])
        if words[W.REQUEST_SEQ] != seq or number <= taken:
            continue
        words[W.MISSED] += number - taken - 1
        taken = number
        started = time.perf_counter_ns()
        routine.run(inputs, outputs)
        took = time.perf_counter_ns() - started
        words[W.RESULT_SEQ] += 1
        result[:routine.out_size] = outputs
        words[W.RESULT_ID] = number
        words[W.RESULT_SEQ] += 1
        words[W.RESULT_NS] = time.monotonic_ns()
        ring[int(words[W.ITEMS]) % RING] = took
        words[W.ITEMS] += 1
        if took > words[W.SERVICE_NS_MAX]:
            words[W.SERVICE_NS_MAX] = took


def _download(words: np.ndarray, download: np.ndarray, memory: int) -> routines.Jacobian | None:
    """Build the routine the download names; answer its sizes, or the reason in the download area."""
    seq = int(words[W.DOWNLOAD_SEQ])
    words[W.STATE] = State.READY
    try:
        blob = msgpack.unpackb(download[:int(words[W.DOWNLOAD_BYTES])].tobytes())
        arrays = {name: np.array(values, dtype=np.float64).reshape(shape) for name, (shape, values) in blob["arrays"].items()}
        routine = routines.build(blob["routine"], arrays, blob["options"])
        if max(routine.in_size, routine.out_size) > memory:
            raise ValueError(f"routine {blob['routine']} needs {max(routine.in_size, routine.out_size)} numbers of memory "
                             f"for its inputs or outputs; the processor has {memory}: raise the device's option memory")
    except Exception as exc:  # the driver raises it in the task's init, with the reason
        text = f"{type(exc).__name__}: {exc}".encode()[: download.size]
        download[:len(text)] = np.frombuffer(text, dtype=np.uint8)
        words[W.ANSWER_BYTES] = len(text)
        words[W.STATE] = State.FAILED
        words[W.DOWNLOAD_ACK] = seq
        return None
    words[W.IN_SIZE] = routine.in_size
    words[W.OUT_SIZE] = routine.out_size
    words[W.ANSWER_BYTES] = 0
    words[W.ITEMS] = words[W.MISSED] = words[W.SERVICE_NS_MAX] = 0
    words[W.RESULT_ID] = 0
    words[W.STATE] = State.LOADED
    words[W.DOWNLOAD_ACK] = seq
    return routine


if __name__ == "__main__":
    sys.exit(main())
