"""What the three simulated I/O boards share: the plant's registers and the channels a task was lent.

A board driver attaches to the register segment the plant created (never creating or removing
it), checks the channels the device database lent it, and precomputes, at open time, the views its
per-cycle calls use: a slice when the channels are consecutive, else an index array for one
`take` or one indexed assignment. It touches no channel it was not lent.
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from drivers.mujoco_arm.registers import W_BOARD_SEQ, W_BOARD_STEP, DeviceError, Registers, attach_registers
from pbo_runtime import DeviceDriver, format_channels

_SPINS_BEFORE_YIELD = 100
_STUCK_AFTER_S = 0.5


class BoardDriver(DeviceDriver):
    """Base of the ADC, DAC and parallel-port drivers: registers, channels, no options."""

    OPTIONS: ClassVar[tuple[str, ...]] = ()
    NEEDS_PLANT: ClassVar[bool] = True

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> None:
        unknown = sorted(set(options) - set(cls.OPTIONS))
        if unknown:
            valid = ", ".join(cls.OPTIONS) or "none"
            raise ValueError(f"unknown {cls.KIND} option(s) {unknown}; valid options: {valid}")

    def __init__(self, registers: str, options: Mapping[str, Any], *, channels: tuple[int, ...] | None = None,
                 io: DeviceDriver | None = None) -> None:
        super().__init__(registers, options, channels=channels)
        self.check_options(self.options)
        if not self.channels:
            raise DeviceError(f"{self.KIND} on registers {registers!r}: no channels to open")
        bad = [c for c in self.channels if not 0 <= c < self.PORTS]
        if bad:
            raise DeviceError(f"{self.KIND} has channels 0-{self.PORTS - 1}; channel(s) {format_channels(bad)} do not exist")
        self._regs: Registers = attach_registers(registers)
        self._words = self._regs.words
        first, last = self.channels[0], self.channels[-1]
        self.contiguous = self.channels == tuple(range(first, last + 1))
        self._slice = slice(first, last + 1)
        self._index = np.array(self.channels, dtype=np.intp)
        self._stuck_deadline = 0.0

    def _lent(self, block: np.ndarray) -> np.ndarray | None:
        """The view of `block` on the lent channels when they are consecutive, else None (use `_index`)."""
        return block[self._slice] if self.contiguous else None

    def _wait_for_conversion(self, tries: int) -> None:
        """Slow path of a seqlocked read: the plant is mid-conversion for long; yield, and give up if stuck."""
        if tries == _SPINS_BEFORE_YIELD:
            self._stuck_deadline = time.monotonic() + _STUCK_AFTER_S
        elif tries > _SPINS_BEFORE_YIELD:
            if time.monotonic() > self._stuck_deadline:
                raise DeviceError(
                    f"{self.KIND} on registers {self.registers!r}: the plant has been mid-conversion for over "
                    f"{_STUCK_AFTER_S} s (board seqlock stuck odd); did the plant process die?")
            os.sched_yield()

    def _read_consistent(self, block: np.ndarray, out: np.ndarray) -> int:
        """Copy the lent channels of a plant-written block under the board seqlock; the plant step it is from."""
        words = self._words
        view = self._lent(block)
        tries = 0
        while True:
            before = words[W_BOARD_SEQ]
            if not before & 1:
                if view is not None:
                    np.copyto(out, view)
                else:
                    block.take(self._index, out=out, mode="clip")
                step: int = words[W_BOARD_STEP]
                if words[W_BOARD_SEQ] == before:
                    return step
            tries += 1
            if tries >= _SPINS_BEFORE_YIELD:
                self._wait_for_conversion(tries)

    def close(self) -> None:
        """Unmap the registers (idempotent); the plant owns and removes the segment."""
        regs = self.__dict__.pop("_regs", None)
        if regs is None:
            return
        self._release_views()
        self.__dict__.pop("_words", None)
        regs.release()

    def _release_views(self) -> None:
        """Drop the subclass's views of the registers before the mapping closes."""
