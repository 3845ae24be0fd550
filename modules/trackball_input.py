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

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pbo_runtime import InVar, ModuleError, OutVar, PortBasedObject, Status


@dataclass(frozen=True)
class TrackballParams:
    script: tuple[tuple[float, ...], ...] = ()  # rows: t, dx, dy, dz, rx, ry, rz
    file: str = ""  # a CSV of the same rows (a header line is allowed)
    device: str = ""  # a trackball device (driver trackball) in the task's resources, read each cycle

    def __post_init__(self) -> None:
        if sum(map(bool, (self.script, self.file, self.device))) != 1:
            raise ValueError("give exactly one of device (a trackball device), script (inline waypoints) or file "
                             "(a CSV of waypoints)")
        if self.script:
            check_waypoints(np.asarray(self.script, dtype=float), "script")


def check_waypoints(rows: np.ndarray, where: str) -> np.ndarray:
    if rows.ndim != 2 or rows.shape[1] != 7 or len(rows) == 0:
        raise ValueError(f"{where}: each waypoint is 7 numbers (t, dx, dy, dz, rx, ry, rz), got shape {list(rows.shape)}")
    if not np.all(np.isfinite(rows)):
        raise ValueError(f"{where}: waypoints must be finite numbers")
    if np.any(np.diff(rows[:, 0]) <= 0) or rows[0, 0] < 0:
        raise ValueError(f"{where}: waypoint times must start at >= 0 and increase, got: {rows[:, 0].tolist()}")
    return rows


class TrackballInput(PortBasedObject):
    """x_d = the pose at `on` + the scripted offset at the time since `on`. Real-time safe cycle."""

    Params = TrackballParams

    x_m = InVar("x_m", shape=(6,), doc="measured Cartesian pose (position m, rotation vector rad)")
    x_d = OutVar("x_d", shape=(6,), doc="desired Cartesian pose")

    def init(self, params: TrackballParams) -> None:
        self._start = np.zeros(6)
        self._offset = np.zeros(6)
        self._started = 0.0
        self._read_offset = None
        if params.device:
            ball = self.open_device(params.device)
            if not callable(getattr(ball, "read_offset", None)):
                raise ModuleError(f"device '{params.device}' is not a trackball (it has no read_offset); give it driver: trackball")
            self._read_offset = ball.read_offset
            return
        if params.file:
            path = Path(params.file)
            try:
                rows = np.atleast_2d(np.genfromtxt(path, delimiter=",", comments="#"))
            except (OSError, ValueError) as exc:
                raise ValueError(f"cannot read trackball file '{path}': {exc}") from None
            rows = rows[~np.isnan(rows).all(axis=1)]  # a header line reads as a row of nan
            rows = check_waypoints(rows, str(path))
        else:
            rows = np.asarray(params.script, dtype=float)
        self._times = rows[:, 0].copy()
        self._offsets = rows[:, 1:].copy()

    def on(self) -> None:
        np.copyto(self._start, self.x_m)
        self._started = self.time
        self.x_d = self.x_m

    def cycle(self) -> Status:
        elapsed = self.time - self._started
        if self._read_offset is not None:
            self._read_offset(elapsed, self._offset)
            np.add(self._start, self._offset, out=self.x_d)
            return Status.CONTINUE
        times, offsets, offset = self._times, self._offsets, self._offset
        k = int(np.searchsorted(times, elapsed))
        if k == 0:
            np.multiply(offsets[0], elapsed / times[0] if times[0] > 0 else 1.0, out=offset)
        elif k >= len(times):
            np.copyto(offset, offsets[-1])
        else:
            share = (elapsed - times[k - 1]) / (times[k] - times[k - 1])
            np.subtract(offsets[k], offsets[k - 1], out=offset)
            np.multiply(offset, share, out=offset)
            np.add(offset, offsets[k - 1], out=offset)
        np.add(self._start, offset, out=self.x_d)
        return Status.CONTINUE
