"""Operator goal input (TR §4.3, aperiodic): a new desired joint position each time an event comes.

An aperiodic task: it runs when the operator sends an event (`pbo event goal 0.3 -0.5 ...`),
not on a timer, with the same transfers as a periodic cycle. When turned on it takes the arm's
current position as the goal, so nothing moves until a goal arrives. The supervisor refuses an
event that is not NDOF finite numbers (`EVENT_SHAPE`); a payload that reaches the cycle anyway
(another sender) of the wrong length is an ERROR return (`pbo clear` returns it to OFF).
"""

from __future__ import annotations

import numpy as np

from pbo_runtime import InVar, OutVar, PortBasedObject, Status


class GoalInput(PortBasedObject):
    """Writes each event's values into q_d. Run it with `aperiodic: true, min_interarrival: ...`."""

    EVENT_SHAPE = ("NDOF",)  # the supervisor refuses an event of another count before it is sent
    # rad (m for a prismatic joint): a typo, never a goal; the arm's limits are the robot interface's
    EVENT_RANGE = (-100.0, 100.0)

    q_m = InVar("q_m", shape=("NDOF",), doc="measured joint position, rad: the goal until one arrives")
    q_d = OutVar("q_d", shape=("NDOF",), doc="desired joint position, rad")

    def init(self, params: object) -> None:
        self._goal = np.zeros(self.q_d.shape)

    def on(self) -> None:
        self.q_d = self.q_m

    def cycle(self) -> Status:
        payload = self.event
        if payload is None:
            return Status.CONTINUE
        values = np.asarray(payload, dtype=float).reshape(-1)
        if values.size != self._goal.size or not np.all(np.isfinite(values)):
            return self.fault(f"a goal has {self._goal.size} finite values, got: {list(payload)}")
        self.q_d = values
        return Status.CONTINUE
