"""Cartesian teleoperation input (TR Figure 10): a 6-DOF trackball's motion as the desired pose.

It turns an operator's motion into a desired pose x_d, as an offset from where the arm was when
the task turned on. The motion comes from one of:

- `device`: a trackball device (driver `trackball`, TR §4.6.2), read each cycle through its
  driver, whose own `source` is a script or the operator in the browser HMI (`pbo play`);
- `script` or `file`: waypoints in the module itself, as before the trackball had a driver
  (time in s since `on`, then dx, dy, dz in m and rx, ry, rz in rad), interpolated linearly and
  held after the last one; inline (`script`) or as a CSV file (`file`) with the same seven
  columns. The file is read in `init`, never in `cycle`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from pbo_runtime import InVar, ModuleError, OutVar, PortBasedObject, Status, Waypoints, param


@dataclass(frozen=True)
class TrackballParams:
    script: tuple[tuple[float, ...], ...] = param((), at_least=-1e6, at_most=1e6)  # rows: t, dx, dy, dz, rx, ry, rz
    file: str = ""  # a CSV of the same rows (a header line is allowed)
    device: str = ""  # a trackball device (driver trackball) in the task's resources, read each cycle

    def __post_init__(self) -> None:
        if sum(map(bool, (self.script, self.file, self.device))) != 1:
            raise ValueError("give exactly one of device (a trackball device), script (inline waypoints) or file "
                             "(a CSV of waypoints)")
        if self.script:
            Waypoints.from_script(self.script)


class TrackballInput(PortBasedObject):
    """x_d = the pose at `on` + the scripted offset at the time since `on`. Real-time safe cycle."""

    Params = TrackballParams
    DEVICES: ClassVar[Mapping[str, Mapping[str, Any]]] = {
        "device": {"kind": "trackball"}}  # when given: a script or a file opens none

    x_m = InVar("x_m", shape=(6,), doc="measured Cartesian pose (position m, rotation vector rad)")
    x_d = OutVar("x_d", shape=(6,), doc="desired Cartesian pose")

    def init(self, params: TrackballParams) -> None:
        self._start = np.zeros(6)
        self._offset = np.zeros(6)
        self._started = 0.0
        self._read_offset: Callable[[float, np.ndarray], object] | None = None
        if params.device:
            ball = self.open_device(params.device)
            if not callable(getattr(ball, "read_offset", None)):
                raise ModuleError(
                    f"device '{params.device}' is not a trackball (it has no read_offset); give it driver: trackball"
                )
            self._read_offset = ball.read_offset
            return
        waypoints = Waypoints.from_csv(params.file) if params.file else Waypoints.from_script(params.script)
        self._read_offset = waypoints.offset_at

    def on(self) -> None:
        np.copyto(self._start, self.x_m)
        self._started = self.time
        self.x_d = self.x_m

    def cycle(self) -> Status:
        assert self._read_offset is not None  # set by init
        self._read_offset(self.time - self._started, self._offset)
        np.add(self._start, self._offset, out=self.x_d)
        return Status.CONTINUE
