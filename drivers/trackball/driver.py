"""The 6-DOF trackball of Cartesian teleoperation (TR Figure 10; §4.6.2 lists a Dimension-4 trackball's SAI driver).

A sensor-actuator driver: `read_offset(elapsed, out)` gives the operator's displacement of the
ball, six numbers (dx, dy, dz in m, then rx, ry, rz in rad), which a module (`trackball_input`
with `device:`) adds to the pose the arm had when it turned on. Where the motion comes from is
the device's `source` option, so the module is the same for both:

- `source: script` (the default): a recorded session replayed, as waypoints (time in s since
  the module turned on, then the six numbers), interpolated linearly and held after the last;
  given inline (`script: [[t, dx, dy, dz, rx, ry, rz], ...]`) or as a CSV file (`file:`, the same
  seven columns, a header line allowed), read when the device is opened, never per cycle;
- `source: hmi`: the operator plays it while the run lives, from the browser HMI's trackball
  panel or the command line (`pbo play DEVICE dx dy dz rx ry rz`): the driver makes the device's
  operator input (`pbo_runtime.OperatorInput`) when its task opens it, and reads the newest values
  each cycle; zeros until the operator first plays it.

Either way, `reach` (m, default 0.3) and `turn` (rad, default 1.0) bound each position and
rotation component: a displacement beyond them is held at the bound (a ball has a travel).
`read_offset` is real-time safe: no allocation, no waiting.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from pbo_runtime import DeviceDriver, OperatorInput, Waypoints

_OPTIONS = ("source", "script", "file", "reach", "turn")
SOURCES = ("script", "hmi")


def _check_options(options: Mapping[str, Any]) -> tuple[str, float, float]:
    unknown = sorted(set(options) - set(_OPTIONS))
    if unknown:
        raise ValueError(f"unknown trackball option(s) {unknown}; valid options: {', '.join(_OPTIONS)}")
    source = options.get("source", "script")
    if source not in SOURCES:
        raise ValueError(f"trackball option source must be one of {', '.join(SOURCES)}, got: {source!r}")
    given = [key for key in ("script", "file") if options.get(key)]
    if source == "script" and len(given) != 1:
        raise ValueError("a trackball with source: script takes exactly one of script (inline waypoints) or file "
                         "(a CSV of waypoints)")
    if source == "hmi" and given:
        raise ValueError(f"a trackball with source: hmi is played by the operator; it takes no {given[0]} "
                         "(give source: script to replay one)")
    if options.get("script"):
        Waypoints.from_script(options["script"], "trackball option script")
    bounds = []
    for key, default, unit in (("reach", 0.3, "m"), ("turn", 1.0, "rad")):
        value = options.get(key, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and 0 < value <= 10):
            raise ValueError(f"trackball option {key} must be a number in (0, 10] ({unit}), got: {value!r}")
        bounds.append(float(value))
    return str(source), bounds[0], bounds[1]


class Trackball(DeviceDriver):
    """A 6-DOF trackball, played by a script or by the operator (options: source, script or file, reach, turn)."""

    KIND = "trackball"
    OPTIONS = _OPTIONS

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> None:
        """ValueError for an unknown or bad option (the checker reports it as E607)."""
        _check_options(options)

    @classmethod
    def operator_controls(cls, options: Mapping[str, Any]) -> list[dict[str, Any]] | None:
        """What the HMI's trackball panel offers when the operator plays it (source: hmi): one
        control per value of `pbo play`, in order, with its unit and travel; None for a script."""
        try:
            source, reach, turn = _check_options(options)
        except ValueError:
            return None
        if source != "hmi":
            return None
        return ([{"name": axis, "unit": "m", "min": -reach, "max": reach} for axis in ("dx", "dy", "dz")]
                + [{"name": axis, "unit": "rad", "min": -turn, "max": turn} for axis in ("rx", "ry", "rz")])

    def __init__(self, registers: str, options: Mapping[str, Any], *, device: str = "trackball", **_: Any) -> None:
        super().__init__(registers, options)
        self.source, reach, turn = _check_options(self.options)
        self.device = device
        self._upper = np.array([reach] * 3 + [turn] * 3)
        self._lower = -self._upper
        self._input: OperatorInput | None = None
        if self.source == "hmi":
            self._input = OperatorInput(registers, device, 6)
            self._read_input = self._input.read
            return
        if self.options.get("file"):
            self._waypoints = Waypoints.from_csv(self.options["file"])
        else:
            self._waypoints = Waypoints.from_script(self.options["script"], "trackball option script")
        self._scripted = self._waypoints.offset_at

    def read_offset(self, elapsed: float, out: np.ndarray) -> bool:
        """Fill out (6,) with the displacement at `elapsed` s since the module turned on (a script's
        clock; the operator's ball ignores it); False while the operator has not played it yet."""
        if self._input is not None:
            played = self._read_input(out)
        else:
            self._scripted(elapsed, out)
            played = True
        np.minimum(out, self._upper, out=out)
        np.maximum(out, self._lower, out=out)
        return played

    def close(self) -> None:
        """Unlink the operator input, if it made one (idempotent)."""
        made, self._input = self._input, None
        if made is not None:
            self.__dict__.pop("_read_input", None)
            made.close()
