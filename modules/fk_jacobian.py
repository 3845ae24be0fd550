"""Forward kinematics and Jacobian (TR Figure 7; used in Figures 10, 12 and 13).

From the measured joint position q_m it publishes the measured Cartesian pose x_m of an
operational frame (by default "ee", the end effector) and that frame's Jacobian J:

    x_m = (p, log3(R))   position in the base frame, then orientation as a rotation vector
    J   = (6, NDOF)      LOCAL_WORLD_ALIGNED: linear-velocity rows first, then angular-velocity
                         rows, both in the base frame, so xd = J qd for the position part and
                         omega = J[3:] qd for the angular velocity

The model is built once in `init` from the robot interface's out-consts ARM and EE (TR §4.3:
the module configures itself for whatever arm is attached). Real-time notes: the cycle allocates
no arrays of its own, but the Pinocchio calls (`computeJointJacobians`, `updateFramePlacement`,
`log3`, `getFrameJacobian`) return small objects the binding allocates.
"""

from __future__ import annotations

from dataclasses import dataclass

from modules._model_based import ModelBased
from modules._robot_model import END_EFFECTOR_FRAME, frame_id, frame_pose_and_jacobian
from pbo_runtime import InVar, OutVar, Status


@dataclass(frozen=True)
class FkJacobianParams:
    frame: str = END_EFFECTOR_FRAME  # the operational frame: "ee" or "link1" ... "link<NDOF>"

    def __post_init__(self) -> None:
        if not self.frame:
            raise ValueError("frame must name a frame of the arm, got: ''")


class FkJacobian(ModelBased):
    """Forward kinematics and Jacobian of the arm the robot interface describes."""

    Params = FkJacobianParams

    q_m = InVar("q_m", shape=("NDOF",), doc="measured joint position, rad")
    x_m = OutVar("x_m", shape=(6,), doc="measured pose: position m, then rotation vector rad, base frame")
    jacobian = OutVar("J", shape=(6, "NDOF"), doc="frame Jacobian, LOCAL_WORLD_ALIGNED, linear rows first")

    def init(self, params: FkJacobianParams) -> None:
        self.build_model()
        self._frame = frame_id(self._model, params.frame)

    def on(self) -> None:
        self._compute()

    def cycle(self) -> Status:
        self._compute()
        return Status.CONTINUE

    def _compute(self) -> None:
        frame_pose_and_jacobian(self._model, self._data, self._frame, self.q_m, self.x_m, self.jacobian)
