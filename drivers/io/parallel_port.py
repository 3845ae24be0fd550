"""The simulated 16-channel parallel port (TR §4.6.1), served by the plant.

Each channel is a 16-line port in both directions: input lines, which the device wired to it
drives (`pio_in`), and output lines, which the driver drives (`pio_out`); one aligned uint16 word
each, with one writer, so no lock. A port has no handshake of its own: the device's protocol
(strobe, acknowledge) is the sensor driver's business (see `drivers.force_torque.parallel`).
Channels 0-7 carry vendor A's force/torque sensor (see `drivers.mujoco_arm.plant`).

Channels are addressed by their position among the lent channels: `read_channel(0)` is the
first channel the task opened, whatever its number on the board.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from drivers.io.board import BoardDriver
from drivers.mujoco_arm.registers import PIO_CHANNELS, DeviceError
from pbo_runtime import DeviceDriver


class ParallelPort(BoardDriver):
    """16-bit input and output lines of the channels it was lent. No options. Real-time safe."""

    PORTS = PIO_CHANNELS
    KIND = "parallel_port"

    def __init__(self, registers: str, options: Mapping[str, Any], *, channels: tuple[int, ...] | None = None,
                 io: DeviceDriver | None = None) -> None:
        super().__init__(registers, options, channels=channels)
        self._in = self._regs.pio_in
        self._out = self._regs.pio_out
        self._in_view = self._lent(self._in)
        # memoryview item access is the cheapest way to move one word from Python
        self._in_words = memoryview(self._regs.pio_in.data).cast("B").cast("H")
        self._out_words = memoryview(self._regs.pio_out.data).cast("B").cast("H")
        self._numbers = self.channels  # position among the lent channels -> channel number on the board

    def read(self, lines_out: np.ndarray) -> None:
        """Fill lines_out (uint16, one per lent channel, in channel order) with the input lines."""
        if self._in_view is not None:
            np.copyto(lines_out, self._in_view)
        else:
            self._in.take(self._index, out=lines_out, mode="clip")

    def read_channel(self, k: int) -> int:
        """The input lines of the k-th lent channel."""
        return self._in_words[self._numbers[k]]

    def write_channel(self, k: int, lines: int) -> None:
        """Drive the output lines of the k-th lent channel (0 .. 65535); anything else (a float, NaN,
        a number out of range) is refused with `DeviceError` and the lines keep their state."""
        try:
            self._out_words[self._numbers[k]] = lines
        except (TypeError, ValueError):  # the memoryview takes only 16-bit integers: nothing was written
            raise DeviceError(f"parallel_port on registers {self.registers!r}: output lines of channel "
                              f"{self._numbers[k]} must be an integer 0 .. 65535, got: {lines!r}") from None

    def output(self, k: int) -> int:
        """The output lines of the k-th lent channel, as last driven."""
        return self._out_words[self._numbers[k]]

    def _release_views(self) -> None:
        for view in (self._in_words, self._out_words):
            view.release()
        for name in ("_in", "_out", "_in_view", "_in_words", "_out_words"):
            self.__dict__.pop(name, None)
