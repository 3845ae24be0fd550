"""Vendor B's wrist force/torque sensor, read through 6 ADC channels (TR §4.6.2).

A sensor-actuator driver giving the same `read_wrench(f_out)` as vendor A's: force (N) and torque
about the sensor origin (N m), in the sensor frame (the tool frame), the wrench the environment
applies to the tool. The sensor's six strain-gauge voltages v become the wrench by its own
calibration sheet, given as device options:

    w = C (v - offset)      calibration: C, 6x6 (rows Fx, Fy, Fz in N/V, Tx, Ty, Tz in N m/V)
                            offset: 6 voltages at no load, V

`read_wrench` reads one ADC conversion (the plant converts every step) and returns True when it
is a conversion the driver had not seen.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, cast

import numpy as np

from drivers.force_torque import models
from drivers.io.adc import Adc
from drivers.mujoco_arm.registers import DeviceError
from pbo_runtime import DeviceDriver

_OPTIONS = ("calibration", "offset")


def _matrix(value: Any, shape: tuple[int, ...], name: str, what: str) -> np.ndarray:
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"ft_analog option {name} must be {what}, got: {value!r}") from None
    if array.shape != shape:
        raise ValueError(f"ft_analog option {name} must be {what}, got shape {array.shape}: {value!r}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"ft_analog option {name} must hold finite numbers, got: {value!r}")
    return array


class AnalogForceTorque(DeviceDriver):
    """Vendor B's F/T sensor on 6 ADC channels. options: `calibration` (6x6), `offset` (6, V). Real-time safe reads."""

    KIND = "force_torque"
    OPTIONS = _OPTIONS

    IO = "adc"
    IO_CHANNELS = models.B_CHANNELS

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> None:
        _calibration_sheet(options)

    def __init__(self, registers: str, options: Mapping[str, Any], *, channels: tuple[int, ...] | None = None,
                 io: DeviceDriver | None = None) -> None:
        super().__init__(registers, options, io=io)
        self.calibration, self.offset = _calibration_sheet(self.options)  # C-contiguous float64, as np.dot needs
        if io is None or getattr(io, "KIND", "") != self.IO:
            raise DeviceError(f"ft_analog needs an ADC (io: {{device: <adc device>, channels: 0-5}}), got: {io!r}")
        if len(io.channels) != self.IO_CHANNELS:
            raise DeviceError(f"ft_analog needs {self.IO_CHANNELS} ADC channels, got {len(io.channels)}")
        self._read = cast(Adc, io).read  # its KIND says so
        self._volts = np.zeros(self.IO_CHANNELS)
        self._step = -1

    def read_wrench(self, f_out: np.ndarray) -> bool:
        """Fill f_out (6,) with the wrench of the newest conversion, N and N m; True if the conversion is new."""
        step = self._read(self._volts)
        volts = self._volts
        np.subtract(volts, self.offset, out=volts)
        np.dot(self.calibration, volts, out=f_out)  # dot, not matmul: matmul allocates a buffer per call
        fresh = step != self._step
        self._step = step
        return fresh

    def close(self) -> None:
        """Close the ADC it reads through (idempotent)."""
        io, self.io = self.io, None
        if io is not None:
            self.__dict__.pop("_read", None)
            io.close()


def _calibration_sheet(options: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """(calibration, offset) from a device's options, or ValueError saying what is wrong."""
    unknown = sorted(set(options) - set(_OPTIONS))
    if unknown:
        raise ValueError(f"unknown ft_analog option(s) {unknown}; valid options: {', '.join(_OPTIONS)}")
    missing = [key for key in _OPTIONS if key not in options]
    if missing:
        raise ValueError(f"ft_analog needs option(s) {', '.join(missing)}: the sensor's calibration sheet "
                         "(calibration: 6 rows of 6, N/V and N m/V; offset: 6 V)")
    calibration = _matrix(options["calibration"], (6, 6), "calibration", "a 6x6 matrix (6 rows of 6 numbers)")
    offset = _matrix(options["offset"], (6,), "offset", "6 voltages")
    if np.linalg.matrix_rank(calibration) < 6:
        raise ValueError("ft_analog option calibration is singular: some wrench would read as zero; check the sheet")
    return calibration, offset
