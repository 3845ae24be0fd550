"""Numbers an operator plays into a device while a run lives: the browser HMI's trackball (TR §4.6.2).

A driver whose source is the operator (`drivers.trackball` with `source: hmi`) makes, when its
task opens it, a small 0600 segment named after the run and the device,
`/pbo.<subsystem>.<run id>.operator-<device>`: a sequence word (odd while written), the number
of writes, the number of values, then the values. The operator's verb `pbo play DEVICE values...`
(and so `POST /api/verbs/play`, which the HMI's trackball panel sends) writes it in the
supervisor; the driver reads it under the sequence, never waiting (a read that meets a write
keeps the values it had). One writer (the supervisor's one thread), one reader (the task).
The driver unlinks it on close; the supervisor's stop removes what a dead task left.
"""

from __future__ import annotations

import contextlib
import math
import mmap

import numpy as np
import posix_ipc

from pbo_runtime.errors import PboError
from pbo_runtime.ipc import shm

SEQ, WRITES, SIZE = 0, 1, 2
HEADER_WORDS = 4


def operator_input_name(registers: str, device: str) -> str:
    """The segment's name, from the run's plant registers name (`/pbo.<subsystem>.<run id>.plant`) and the device."""
    prefix = registers.rsplit(".", 1)[0] if registers.count(".") >= 3 else registers
    return f"{prefix}.operator-{device}"


class OperatorInput:
    """The reading end, made by the driver: `read(out)` copies the newest values the operator played."""

    def __init__(self, registers: str, device: str, size: int) -> None:
        self.name = operator_input_name(registers, device)
        self.size = size
        _segment, self._mapping = shm.create_segment(self.name, (HEADER_WORDS + size) * 8)
        self._words = np.frombuffer(self._mapping, dtype=np.int64, count=HEADER_WORDS)
        self._values = np.frombuffer(self._mapping, dtype=np.float64, count=size, offset=HEADER_WORDS * 8)
        self._words[SIZE] = size
        self._taking = np.zeros(size)
        self._held = np.zeros(size)  # the newest complete values (zeros: the operator has not played yet)
        self._seen = np.zeros(1, dtype=np.int64)  # the sequence of the values held: updated in place, nothing boxed to keep

    def read(self, out: np.ndarray) -> bool:
        """Copy the newest complete values the operator played into `out` (zeros until the first);
        True once any were played. Real-time safe: no allocation, no waiting (a read that meets a
        write gives the values before it)."""
        words, seen = self._words, self._seen
        seq = words[SEQ]
        if seq != seen[0] and not seq & 1:
            np.copyto(self._taking, self._values)
            if words[SEQ] == seq:
                np.copyto(self._held, self._taking)
                seen[0] = seq
        np.copyto(out, self._held)
        return bool(seen[0])

    def close(self) -> None:
        """Unmap and unlink (idempotent)."""
        mapping = self.__dict__.pop("_mapping", None)
        if mapping is None:
            return
        for name in ("_words", "_values"):
            self.__dict__.pop(name, None)
        shm.unlink_quietly("shm", self.name)
        with contextlib.suppress(BufferError):  # a view outlives it: the mapping goes with that view
            mapping.close()


def play(subsystem: str, run_id: str, device: str, values: list[float]) -> int:
    """Write `values` into device `device`'s operator input of run `run_id` (the supervisor's side).

    PboError when the device has no operator input in this run (its task is not open, or its
    source is not the operator), when the segment is not this user's 0600 one, or when the values
    are not as many finite numbers as the device takes. Returns the number of writes so far.
    """
    name = operator_input_name(shm.object_name(subsystem, run_id, "plant"), device)
    exists, why = shm.look_at("shm", name)
    if not exists:
        raise PboError(f"device '{device}' takes no operator input in this run: no task has it open with the operator "
                       "as its source (a trackball with source: hmi, in a task that is spawned)")
    if why is not None:
        raise PboError(f"device '{device}': its operator input {name} is not to be trusted ({why}); not written")
    try:
        mapping = shm.attach_segment(name)
    except (posix_ipc.Error, OSError, ValueError) as exc:
        raise PboError(f"device '{device}': cannot open its operator input ({exc})") from None
    try:
        return _write(mapping, device, values)
    finally:
        mapping.close()


def _write(mapping: mmap.mmap, device: str, values: list[float]) -> int:
    words = np.frombuffer(mapping, dtype=np.int64, count=HEADER_WORDS)
    size = int(words[SIZE])
    if len(values) != size or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
        del words
        raise PboError(f"device '{device}' takes {size} finite numbers, got: {values}")
    target = np.frombuffer(mapping, dtype=np.float64, count=size, offset=HEADER_WORDS * 8)
    words[SEQ] += 1
    target[:] = values
    words[WRITES] += 1
    words[SEQ] += 1
    writes = int(words[WRITES])
    del words, target  # no view may outlive the mapping
    return writes


__all__ = ["OperatorInput", "operator_input_name", "play"]
