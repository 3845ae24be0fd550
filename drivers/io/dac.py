"""The simulated 4-channel, 16-bit digital-to-analog converter (TR §4.6.1), served by the plant.

Channels 0-1 are looped back to the ADC's channels 6-7 (see `drivers.mujoco_arm.plant`); 2-3 are
free. Each channel is one aligned int16 register with one writer, the task lent it, so a write
needs no lock; the plant reads them at its next step. Closing the driver sets its channels to 0 V.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from drivers.io.board import BoardDriver
from drivers.mujoco_arm.registers import DAC_CHANNELS, VOLTS_PER_COUNT, DeviceError
from pbo_runtime import DeviceDriver


class Dac(BoardDriver):
    """Writes voltages to the channels it was lent (clipped to +-10 V). No options. Real-time safe writes."""

    PORTS = DAC_CHANNELS
    KIND = "dac"
    volts_per_count = VOLTS_PER_COUNT

    def __init__(self, registers: str, options: Mapping[str, Any], *, channels: tuple[int, ...] | None = None,
                 io: DeviceDriver | None = None) -> None:
        super().__init__(registers, options, channels=channels)
        self._dac = self._regs.dac
        self._view = self._lent(self._dac)
        n = len(self.channels)
        self._scaled = np.zeros(n)
        self._counts = np.zeros(n, dtype=np.int16)
        # arrays, not Python scalars (boxed on every call), and minimum/maximum, not clip (which allocates)
        self._per_volt = np.full(n, 1.0 / VOLTS_PER_COUNT)
        self._lowest = np.full(n, -32768.0)
        self._highest = np.full(n, 32767.0)
        self._finite = np.zeros(n, dtype=bool)  # per channel: the voltage is finite (filled per write, no allocation)

    def write(self, volts: np.ndarray) -> None:
        """Set the lent channels (one value per channel, in channel order), V; rounded to counts.

        NaN or Inf is refused (`DeviceError`) and nothing is written: the channels keep their values.
        """
        if np.count_nonzero(np.isfinite(volts, out=self._finite)) != self._finite.size:  # two C calls, no array
            raise DeviceError(f"dac on registers {self.registers!r}: refused voltages that are not finite "
                              f"([{', '.join(f'{x:g}' for x in np.ravel(volts))}]) for channels "
                              f"{list(self.channels)}; the channels keep their values: fix the task that computes them")
        scaled = self._scaled
        np.multiply(volts, self._per_volt, out=scaled)
        np.rint(scaled, out=scaled)
        np.minimum(scaled, self._highest, out=scaled)
        np.maximum(scaled, self._lowest, out=scaled)
        if self._view is not None:
            np.copyto(self._view, scaled, casting="unsafe")
        else:
            np.copyto(self._counts, scaled, casting="unsafe")
            self._dac[self._index] = self._counts

    def _release_views(self) -> None:
        self._scaled[:] = 0.0
        self.write(self._scaled)  # a released channel goes back to 0 V
        for name in ("_dac", "_view"):
            self.__dict__.pop(name, None)
