"""Data logger (TR §4.1: a task that only gathers data): chosen variables, every cycle, to a file.

Its inputs are the variables named in `params.variables` (one in-var each, of the variable's
own dtype and shape). Rows go into a buffer preallocated for `capacity` seconds, so the cycle
does no I/O and no allocation; the file (`.npz`: a `time` column and one array per variable)
is written on `off` and on `kill`. Rows past the capacity are counted, not silently lost.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from pbo_runtime import ANY_DTYPE, InVar, PortBasedObject, PortSpec, Status


@dataclass(frozen=True)
class DataLoggerParams:
    variables: tuple[str, ...]
    path: str = "runs/log.npz"
    capacity: float = 120.0  # seconds of rows kept

    def __post_init__(self) -> None:
        if not self.variables:
            raise ValueError("variables must name at least one variable to log")
        if len(set(self.variables)) != len(self.variables):
            raise ValueError(f"variables must not repeat, got: {list(self.variables)}")
        if self.capacity <= 0:
            raise ValueError(f"capacity must be > 0 s, got: {self.capacity}")
        if not self.path.endswith(".npz"):
            raise ValueError(f"path must end in .npz, got: {self.path!r}")


class DataLogger(PortBasedObject):
    """Logs chosen variables every cycle; flushes to `path` on off and kill."""

    Params = DataLoggerParams

    @classmethod
    def ports_for(cls, params: DataLoggerParams) -> tuple[PortSpec, ...]:
        extra = tuple(InVar(name, dtype=ANY_DTYPE, shape=None, doc=f"logged variable {name}").spec for name in params.variables)
        named = tuple(PortSpec(name, p.kind, p.variable, p.dtype, p.shape, p.doc) for name, p in zip(params.variables, extra))
        return cls.ports() + named

    def init(self, params: DataLoggerParams) -> None:
        self._names = params.variables
        self._path = self.output_path(params.path)
        self._rows = max(1, int(round(params.capacity / self.period)))
        arrays = self.bound_arrays[-len(self._names):]
        self._sources = [a.reshape(-1) for a in arrays]  # flat views, made once
        # Written now (np.full, not the lazily mapped np.zeros): a row in a page never touched
        # would be faulted in by the cycle that writes it.
        self._columns = [np.full((self._rows, a.size), 0, dtype=a.dtype) for a in arrays]
        self._shapes = [a.shape for a in arrays]
        self._times = np.full(self._rows, 0.0)
        self._pairs = list(zip(self._columns, self._sources))
        self.logged = 0
        self.dropped = 0

    def cycle(self) -> Status:
        row = self.logged
        if row >= self._rows:
            self.dropped += 1
            return Status.CONTINUE
        self._times[row] = self.time
        for column, source in self._pairs:
            column[row] = source
        self.logged = row + 1
        return Status.CONTINUE

    def off(self) -> None:
        self.flush()

    def kill(self) -> None:
        if hasattr(self, "_columns"):
            self.flush()

    def flush(self) -> None:
        """Write every row so far (the whole file again: it stays valid whenever we stop)."""
        n = self.logged
        data = {"time": self._times[:n], "dropped": np.array(self.dropped)}
        for name, column, shape in zip(self._names, self._columns, self._shapes):
            data[name] = column[:n].reshape((n, *shape))
        self._path.parent.mkdir(parents=True, exist_ok=True)
        partial = self._path.with_name(self._path.name + ".part.npz")
        np.savez(partial, **data)
        os.replace(partial, self._path)
