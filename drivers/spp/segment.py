"""The memory a special-purpose processor shares with its driver: header words, then three areas.

The driver creates the segment (0600, named after the run) and the semaphore that wakes the
processor; the processor maps them. Every word has one writer:

- the driver writes the download (a msgpack blob: the routine's name and its data), the request
  (inputs and the request's number, under the REQUEST_SEQ seqlock) and posts the semaphore;
- the processor writes its state, the download's answer, the result (outputs and the number of
  the request they answer, under the RESULT_SEQ seqlock) and its own figures.

Neither side ever waits on the other on the per-cycle path: a request overwrites one the
processor has not taken yet (a miss), and a result the driver finds mid-write is read next call.
"""

from __future__ import annotations

import mmap

import numpy as np

MAGIC = 0x5050_5350  # "PPSP"
HEADER_WORDS = 32
RING = 1024  # service times kept for the percentiles


class W:
    """Header word indexes (int64)."""

    MAGIC = 0
    PID = 1  # the processor's pid, once it runs
    STATE = 2  # STARTING, READY (no routine), LOADED, FAILED
    DOWNLOAD_SEQ = 3  # driver: bumped after writing a download
    DOWNLOAD_ACK = 4  # processor: DOWNLOAD_SEQ of the last download it took
    DOWNLOAD_BYTES = 5  # driver: length of the blob in the download area
    ANSWER_BYTES = 6  # processor: length of the error text in the download area (0: loaded)
    IN_SIZE = 7  # processor: float64 inputs the loaded routine takes
    OUT_SIZE = 8  # processor: float64 outputs it gives
    REQUEST_SEQ = 9  # driver: odd while it writes a request
    REQUEST_ID = 10  # driver: 1, 2, 3, ... one per call
    RESULT_SEQ = 11  # processor: odd while it writes a result
    RESULT_ID = 12  # processor: the REQUEST_ID the result answers
    ITEMS = 13  # processor: work items done
    MISSED = 14  # processor: requests overwritten before it took them
    SERVICE_NS_MAX = 15  # processor: the longest service time, ns
    RESULT_NS = 16  # processor: CLOCK_MONOTONIC ns at which it published its newest result


class State:
    STARTING = 0
    READY = 1
    LOADED = 2
    FAILED = 3


def layout(memory: int, download_bytes: int) -> dict[str, tuple[int, int]]:
    """Byte (offset, size) of each area for `memory` float64 inputs/outputs and a download area."""
    offset = HEADER_WORDS * 8
    areas = {}
    for name, size in (("ring", RING * 8), ("request", memory * 8), ("result", memory * 8), ("download", download_bytes)):
        areas[name] = (offset, size)
        offset += size
    areas["total"] = (0, offset)
    return areas


def views(
    buffer: mmap.mmap, memory: int, download_bytes: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(header words, service-time ring ns, request area, result area, download bytes) over a mapping."""
    areas = layout(memory, download_bytes)
    words = np.frombuffer(buffer, dtype=np.int64, count=HEADER_WORDS)

    def area(name: str, dtype: type) -> np.ndarray:
        offset, size = areas[name]
        return np.frombuffer(buffer, dtype=dtype, count=size // np.dtype(dtype).itemsize, offset=offset)

    return words, area("ring", np.int64), area("request", np.float64), area("result", np.float64), area("download", np.uint8)
