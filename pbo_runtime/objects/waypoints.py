"""Timed waypoints of six numbers, interpolated linearly: a recorded trackball session.

The trackball driver (`source: script`) and the `trackball_input` module (`script:` or `file:`)
replay the same rows, `t, dx, dy, dz, rx, ry, rz` (t in s since the module turned on), so both
read, check and interpolate them here. Rows are read and checked when the device or module is
opened; `offset_at` is real-time safe: no allocation, no waiting.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

COLUMNS = 7  # t, then dx, dy, dz (m) and rx, ry, rz (rad)


def check_waypoints(rows: np.ndarray, where: str) -> np.ndarray:
    """The rows, or ValueError naming `where` when they are not 7 finite numbers with rising times."""
    if rows.ndim != 2 or rows.shape[1] != COLUMNS or len(rows) == 0:
        raise ValueError(f"{where}: each waypoint is 7 numbers (t, dx, dy, dz, rx, ry, rz), got shape {list(rows.shape)}")
    if not np.all(np.isfinite(rows)):
        raise ValueError(f"{where}: waypoints must be finite numbers")
    if np.any(np.diff(rows[:, 0]) <= 0) or rows[0, 0] < 0:
        raise ValueError(f"{where}: waypoint times must start at >= 0 and increase, got: {rows[:, 0].tolist()}")
    return rows


class Waypoints:
    """Offsets at times: from zero to the first waypoint, linear between, held after the last."""

    def __init__(self, rows: np.ndarray, where: str) -> None:
        rows = check_waypoints(np.asarray(rows, dtype=float), where)
        self._times = rows[:, 0].copy()
        self._offsets = rows[:, 1:].copy()

    @classmethod
    def from_script(cls, script: Sequence[Sequence[float]], where: str = "script") -> Waypoints:
        """Waypoints given inline in YAML; ValueError when they are not rows of numbers."""
        try:
            rows = np.asarray(script, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"{where} must be rows of 7 numbers, got: {script!r}") from None
        return cls(rows, where)

    @classmethod
    def from_csv(cls, path: str | Path) -> Waypoints:
        """Waypoints from a CSV of the same seven columns (a header line and # comments allowed)."""
        try:
            rows = np.atleast_2d(np.genfromtxt(path, delimiter=",", comments="#"))
        except (OSError, ValueError) as exc:
            raise ValueError(f"cannot read trackball file '{path}': {exc}") from None
        return cls(rows[~np.isnan(rows).all(axis=1)], str(path))  # a header line reads as a row of nan

    def offset_at(self, elapsed: float, out: np.ndarray) -> None:
        """Fill out (6,) with the offset `elapsed` s after the start."""
        times, offsets = self._times, self._offsets
        k = int(np.searchsorted(times, elapsed))
        if k == 0:
            np.multiply(offsets[0], elapsed / times[0] if times[0] > 0 else 1.0, out=out)
        elif k >= len(times):
            np.copyto(out, offsets[-1])
        else:
            share = (elapsed - times[k - 1]) / (times[k] - times[k - 1])
            np.subtract(offsets[k], offsets[k - 1], out=out)
            np.multiply(out, share, out=out)
            np.add(out, offsets[k - 1], out=out)
