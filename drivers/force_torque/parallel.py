"""Vendor A's wrist force/torque sensor, read through a parallel port (TR §4.6.2).

A sensor-actuator driver: it owns the protocol, the scaling and the synchronisation of one
sensor, and gives the same thing as any F/T driver, `read_wrench(f_out)`: force (N) and torque
about the sensor origin (N m), in the sensor frame (the tool frame, DH frame n), the wrench the
environment applies to the tool. The wiring and protocol are in `models` (8 parallel-port channels:
six 16-bit data words, ACK, STATUS, and a REQUEST output word as the strobe).

Reading is pipelined so a cycle never waits on the sensor: each `read_wrench` takes the reading
that answers the previous request (ACK == REQUEST), then strobes the next request, which the sensor
serves within one plant step. If the answer is not there yet (the task runs faster than the
sensor), the last reading is kept and `read_wrench` returns False; if no answer comes for
`timeout` seconds (option, default 0.5), it raises DeviceError: the sensor is gone.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from typing import Any, cast

import numpy as np

from drivers.force_torque import models
from drivers.io.parallel_port import ParallelPort
from drivers.mujoco_arm.registers import DeviceError
from pbo_runtime import DeviceDriver

_OPTIONS = ("timeout",)


class ParallelForceTorque(DeviceDriver):
    """Vendor A's F/T sensor on 8 parallel-port channels. options: `timeout` (s). Real-time safe reads."""

    KIND = "force_torque"
    OPTIONS = _OPTIONS

    IO = "parallel_port"
    IO_CHANNELS = models.A_CHANNELS

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> None:
        unknown = sorted(set(options) - set(_OPTIONS))
        if unknown:
            raise ValueError(f"unknown ft_parallel option(s) {unknown}; valid options: {', '.join(_OPTIONS)}")
        timeout = options.get("timeout", 0.5)
        if (
            isinstance(timeout, bool)
            or not isinstance(timeout, (int, float))
            or not (math.isfinite(timeout) and 0 < timeout <= 3600)
        ):
            raise ValueError(f"ft_parallel option timeout must be a number of seconds in (0, 3600], got: {timeout!r}")

    def __init__(self, registers: str, options: Mapping[str, Any], *, channels: tuple[int, ...] | None = None,
                 io: DeviceDriver | None = None) -> None:
        super().__init__(registers, options, io=io)
        self.check_options(self.options)
        if io is None or getattr(io, "KIND", "") != self.IO:
            raise DeviceError(
                f"ft_parallel needs a parallel port (io: {{device: <parallel_port device>, channels: 0-7}}), got: {io!r}"
            )
        if len(io.channels) != self.IO_CHANNELS:
            raise DeviceError(f"ft_parallel needs {self.IO_CHANNELS} parallel-port channels, got {len(io.channels)}")
        self.timeout = float(self.options.get("timeout", 0.5))
        port = cast(ParallelPort, io)  # its KIND says so
        self._read_channel = port.read_channel
        self._write_channel = port.write_channel
        self._read_lines = port.read
        if not self._read_channel(models.A_STATUS) & models.A_STATUS_POWERED:
            raise DeviceError(
                f"no vendor A force/torque sensor answers on parallel-port channels {list(io.channels)} (STATUS has "
                "no power bit): is its cable on these channels? (the plant wires it to channels 0-7)")
        self._lines = np.zeros(self.IO_CHANNELS, dtype=np.uint16)
        self._data = self._lines[models.A_DATA : models.A_DATA + 6].view(np.int16)
        self._last = np.zeros(6)
        self._waiting_since = 0.0
        self.readings = 0  # answers taken since the driver was opened
        self._request = 0
        self._strobe(self._read_channel(models.A_ACK))

    def _strobe(self, previous: int) -> None:
        self._request = previous % 0xFFFF + 1  # 1 .. 65535: never the power-on 0, never the last answer
        self._waiting_since = 0.0
        self._write_channel(models.A_REQUEST, self._request)

    def read_wrench(self, f_out: np.ndarray) -> bool:
        """Fill f_out (6,) with the newest reading, N and N m; True if it answers a request made since the last call."""
        if self._read_channel(models.A_ACK) != self._request:
            if self._waiting_since == 0.0:
                self._waiting_since = time.monotonic()
            elif time.monotonic() - self._waiting_since > self.timeout:
                raise DeviceError(
                    f"vendor A force/torque sensor: no answer to request {self._request} for over {self.timeout} s "
                    "(ACK never matched REQUEST); is the plant running?")
            np.copyto(f_out, self._last)
            return False
        self._read_lines(self._lines)  # ACK was read first: the sensor wrote the data before it
        np.copyto(self._last, self._data)  # counts, then scaled in place: no casting buffer
        np.multiply(self._last, models.A_SCALE, out=self._last)
        self.readings += 1
        self._strobe(self._request)
        np.copyto(f_out, self._last)
        return True

    @property
    def clipped(self) -> bool:
        """True if the last reading hit the sensor's full scale on some axis."""
        return bool(self._read_channel(models.A_STATUS) & models.A_STATUS_CLIPPED)

    def close(self) -> None:
        """Close the parallel port it reads through (idempotent)."""
        io, self.io = self.io, None
        if io is not None:
            self.__dict__.pop("_read_channel", None)
            self.__dict__.pop("_write_channel", None)
            self.__dict__.pop("_read_lines", None)
            io.close()
