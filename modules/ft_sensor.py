"""Force/torque sensor interface (TR §4.6.2): the measured wrench `f_m`, whichever sensor is fitted.

It opens the sensor device its params name and copies the driver's reading into `f_m` every
cycle. Any force/torque sensor-actuator driver will do (vendor A's `ft_parallel` on a parallel
port, vendor B's `ft_analog` on an ADC): each turns its raw data into the same SI wrench, so
swapping the sensor is a change of the device's YAML only. Real-time safe cycle: one driver call.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from pbo_runtime import ModuleError, OutVar, PortBasedObject, Status


@dataclass(frozen=True)
class FtSensorParams:
    device: str = "ft"  # the YAML device this task opens (listed in its resources)


class FtSensor(PortBasedObject):
    """f_m from a force/torque sensor's driver (`read_wrench`). Real-time safe cycle."""

    Params = FtSensorParams
    DEVICES: ClassVar[Mapping[str, Mapping[str, Any]]] = {"device": {"kind": "force_torque"}}

    f_m = OutVar("f_m", shape=(6,), doc="measured wrench on the tool at the wrist sensor: force N, torque N m "
                                        "about the sensor origin, in the tool frame")

    def init(self, params: FtSensorParams) -> None:
        sensor = self.open_device(params.device)
        if not callable(getattr(sensor, "read_wrench", None)):
            raise ModuleError(f"device '{params.device}' is not a force/torque sensor (its driver has no read_wrench); "
                              "give it driver: ft_parallel or ft_analog")
        self._read = sensor.read_wrench
        self.fresh = 0  # cycles that brought a new reading (for logs and tests)

    def on(self) -> None:
        self._read(self.f_m)

    def cycle(self) -> Status:
        if self._read(self.f_m):
            self.fresh += 1
        return Status.CONTINUE
