"""Position inverse kinematics (TR Figure 7; the "inverse kinematics" of Figure 12).

Joint positions q_r that put the operational frame at the pose x_d, by damped Newton iterations
on the arm's Pinocchio model (built once in `init` from the robot interface's out-consts ARM and
EE). Each cycle starts from its last answer (from q_m when turned on), so a desired pose that
moves a little per cycle takes one or two iterations:

    repeat at most max_iterations times:
        e  = (p_d - p(q), log3(R_d R(q)^T))        the pose error in the base frame
        stop when |e| <= tolerance                  converged
        dq = J^T (J J^T + damping^2 I)^-1 e         a damped Newton (Levenberg-Marquardt) step
        dq scaled down as a whole to at most max_step rad on any joint
        q  = q + dq

A pose the arm cannot reach leaves the iterations at the nearest pose they find (the damping
keeps them bounded there). The module always publishes that q_r, and `ik_residual` the pose error
left (m and rad, the norm of e): 0 up to `tolerance` when converged. With `unreachable: error` a
cycle that does not converge also reports an error (the task's error component runs; its message
was made in `init`). Joint limits are not imposed.

Poses are (6,): position m, then a rotation vector rad (axis * angle), as fk_jacobian publishes.
Real-time notes: the cycle allocates no arrays of its own, but `numpy.linalg.solve` (6 x 6) and
the Pinocchio calls allocate small results inside the libraries, as in resolved_rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from modules._model_based import ModelBased
from modules._robot_model import END_EFFECTOR_FRAME, frame_id, frame_pose_and_jacobian, limit_speed, pose_error
from pbo_runtime import InVar, OutVar, Status, param


@dataclass(frozen=True)
class InverseKinematicsParams:
    tolerance: float = param(1e-9, above=0, at_most=1)  # m and rad: |e| at which the iterations stop
    max_iterations: int = param(20, at_least=1, at_most=1000)  # per cycle (and at `on`)
    damping: float = param(1e-3, above=0, at_most=10)  # lambda of the damped Newton step (units of J: m and rad)
    max_step: float = param(0.5, above=0, at_most=10)  # rad: no joint moves more than this in one iteration
    unreachable: Literal["continue", "error"] = "continue"  # what a cycle that does not converge does
    frame: str = END_EFFECTOR_FRAME  # the operational frame whose pose x_d gives

    def __post_init__(self) -> None:
        for name in ("tolerance", "damping", "max_step"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got: {value}")
        if not self.max_iterations >= 1:
            raise ValueError(f"max_iterations must be >= 1, got: {self.max_iterations}")
        if self.unreachable not in ("continue", "error"):
            raise ValueError(f"unreachable must be 'continue' or 'error', got: {self.unreachable!r}")
        if not self.frame:
            raise ValueError("frame must name a frame of the arm, got: ''")


class InverseKinematics(ModelBased):
    """q_r with pose(q_r) = x_d, by damped Newton; ik_residual says how near it came."""

    Params = InverseKinematicsParams

    q_m = InVar("q_m", shape=("NDOF",), doc="measured joint position, rad: where the search starts when turned on")
    x_d = InVar("x_d", shape=(6,), doc="desired pose: position m, then rotation vector rad, base frame")
    q_r = OutVar("q_r", shape=("NDOF",), doc="reference joint position, rad")
    residual = OutVar("ik_residual", doc="pose error left by the iterations (norm, m and rad); <= tolerance when converged")

    def init(self, params: InverseKinematicsParams) -> None:
        n = int(self.ndof)
        self.build_model()
        self._frame = frame_id(self._model, params.frame)
        self._tolerance_squared = params.tolerance**2
        self._iterations = params.max_iterations
        self._damping_squared = params.damping**2
        self._max_step = params.max_step
        self._fail = params.unreachable == "error"
        self._message = (
            f"inverse kinematics did not reach x_d within {params.tolerance:g} in {params.max_iterations} iterations "
            "(unreachable, or too far in one cycle); q_r is the nearest found"
        )
        self._x = np.zeros(6)
        self._error = np.zeros(6)
        self._jacobian = np.zeros((6, n))
        self._gram = np.zeros((6, 6))
        self._diagonal = self._gram.reshape(-1)[::7]  # a view of its diagonal
        self._solution = np.zeros(6)
        self._step = np.zeros(n)
        self._scratch = np.zeros(n)
        self.converged = False  # of the last cycle (for tests and logs)
        self.iterations = 0  # Newton steps the last cycle took

    def on(self) -> None:
        # Where the arm is, until the first cycle, which runs at the same boundary and searches
        # from here: a search here would only lengthen the switch that turns this task on.
        self.q_r = self.q_m

    def cycle(self) -> Status:
        if self._solve() or not self._fail:
            return Status.CONTINUE
        return self.fault(self._message)

    def _solve(self) -> bool:
        """Iterate from the current q_r; True when the pose error fell to the tolerance."""
        q, x, e, jacobian, gram = self.q_r, self._x, self._error, self._jacobian, self._gram
        steps = 0
        converged = False
        while True:
            frame_pose_and_jacobian(self._model, self._data, self._frame, q, x, jacobian)
            pose_error(self.x_d, x, e)
            squared = float(np.dot(e, e))
            if squared <= self._tolerance_squared:
                converged = True
                break
            if steps == self._iterations:
                break
            np.matmul(jacobian, jacobian.T, out=gram)
            np.add(self._diagonal, self._damping_squared, out=self._diagonal)
            np.copyto(self._solution, np.linalg.solve(gram, e))
            np.matmul(jacobian.T, self._solution, out=self._step)
            limit_speed(self._step, self._max_step, self._scratch)
            np.add(q, self._step, out=q)
            steps += 1
        self.residual.fill(math.sqrt(squared))
        self.converged, self.iterations = converged, steps
        return converged
