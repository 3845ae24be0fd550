"""What a simulated arm is, as plain data: DH kinematics, link dynamics, limits and home pose.

The same two arrays (`dh`, `dyn`) feed the MuJoCo plant (through `drivers.robots.mjcf`) and the
controllers' Pinocchio model (`modules._robot_model`), so the plant and the model a controller
computes with agree by construction and a test can prove it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Columns of `RobotDescription.dh`.
DH_COLUMNS = ("theta_offset", "d", "a", "alpha")
#: Columns of `RobotDescription.dyn`: COM and inertia about the COM are in link frame i.
DYN_COLUMNS = ("mass", "cx", "cy", "cz", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz", "armature")


def _frozen(values: object, shape: tuple[int, ...], what: str, robot: str) -> np.ndarray:
    array = np.array(values, dtype=np.float64)
    if array.shape != shape:
        raise ValueError(f"robot {robot!r}: {what} must have shape {shape}, got: {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"robot {robot!r}: {what} must be finite, got: {array}")
    array.setflags(write=False)  # a description is immutable data, arrays included
    return array


@dataclass(frozen=True, eq=False)
class RobotDescription:
    """A serial arm of revolute joints, standard (distal) DH: T_i = Rz(q_i+theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i).

    Units: m, rad, kg, kg m², N m s/rad (damping), N m (torque limits), rad/s (velocity limits).
    """

    name: str
    ndof: int
    dh: np.ndarray  # (n, 4): theta_offset, d, a, alpha
    dyn: np.ndarray  # (n, 11): mass, cx, cy, cz, Ixx, Iyy, Izz, Ixy, Ixz, Iyz, armature
    damping: np.ndarray  # (n,) viscous joint friction
    joint_limits: np.ndarray  # (n, 2) lower, upper
    torque_limits: np.ndarray  # (n,) symmetric: |tau_i| <= torque_limits[i]
    q0: np.ndarray  # (n,) home pose; the plant starts braked here
    velocity_limits: np.ndarray | None = None  # (n,) |qd_i| <= velocity_limits[i]; None (or 0 for a joint): not given

    def __post_init__(self) -> None:
        n = self.ndof
        if n < 1:
            raise ValueError(f"robot {self.name!r}: ndof must be >= 1, got: {n}")
        set_ = object.__setattr__  # frozen: normalise the arrays once, here
        set_(self, "dh", _frozen(self.dh, (n, 4), "dh", self.name))
        set_(self, "dyn", _frozen(self.dyn, (n, 11), "dyn", self.name))
        set_(self, "damping", _frozen(self.damping, (n,), "damping", self.name))
        set_(self, "joint_limits", _frozen(self.joint_limits, (n, 2), "joint_limits", self.name))
        set_(self, "torque_limits", _frozen(self.torque_limits, (n,), "torque_limits", self.name))
        set_(self, "q0", _frozen(self.q0, (n,), "q0", self.name))
        velocity = np.zeros(n) if self.velocity_limits is None else self.velocity_limits
        set_(self, "velocity_limits", _frozen(velocity, (n,), "velocity_limits", self.name))
        self._check_physical()

    @property
    def dims(self) -> dict[str, int]:
        """The named sizes a subsystem's ports may use without `dims:` giving them (the checker asks)."""
        return {"NDOF": self.ndof}

    def limit_rows(self) -> list[dict[str, object]]:
        """Each joint's limits as `pbo check` shows them (`limit_rows`): what the robot interface enforces."""
        names = tuple(f"joint{j + 1}" for j in range(self.ndof))
        return limit_rows(names, np.zeros(self.ndof, dtype=bool), self.torque_limits, self.velocity_limits,  # type: ignore[arg-type]
                          self.joint_limits)

    def _check_physical(self) -> None:
        """Refuse what a simulator cannot integrate, naming the link and the rule."""
        for i, row in enumerate(self.dyn, start=1):
            mass, ixx, iyy, izz = row[0], row[4], row[5], row[6]
            if mass <= 0:
                raise ValueError(f"robot {self.name!r}: link {i} mass must be > 0, got: {mass}")
            inertia = inertia_matrix(row)
            eig = np.linalg.eigvalsh(inertia)
            if eig[0] <= 0:
                raise ValueError(
                    f"robot {self.name!r}: link {i} inertia must be positive definite, got eigenvalues {eig}"
                )
            a, b, c = np.sort(eig)
            if a + b < c * (1 - 1e-9):
                raise ValueError(
                    f"robot {self.name!r}: link {i} principal inertias must satisfy the triangle inequality, "
                    f"got: {a:g} + {b:g} < {c:g} (Ixx, Iyy, Izz = {ixx:g}, {iyy:g}, {izz:g})"
                )
            if row[10] < 0:
                raise ValueError(f"robot {self.name!r}: link {i} armature must be >= 0, got: {row[10]}")
        if np.any(self.damping < 0):
            raise ValueError(f"robot {self.name!r}: damping must be >= 0, got: {self.damping}")
        if np.any(self.velocity_limits < 0):  # type: ignore[operator]
            raise ValueError(f"robot {self.name!r}: velocity limits must be >= 0 (0: none given), got: {self.velocity_limits}")
        if np.any(self.torque_limits <= 0):
            raise ValueError(f"robot {self.name!r}: torque limits must be > 0, got: {self.torque_limits}")
        lower, upper = self.joint_limits[:, 0], self.joint_limits[:, 1]
        if np.any(lower >= upper):
            raise ValueError(f"robot {self.name!r}: joint limits must have lower < upper, got: {self.joint_limits}")
        if np.any(self.q0 < lower) or np.any(self.q0 > upper):
            raise ValueError(f"robot {self.name!r}: q0 must lie within the joint limits, got: {self.q0}")


def limit_rows(names: tuple[str, ...], slide: np.ndarray, effort: np.ndarray, velocity: np.ndarray,
               joint_limits: np.ndarray) -> list[dict[str, object]]:
    """One row a joint: name, unit of position (rad or m), effort, velocity (None: none given),
    lower and upper (None: no range). The robot interface clips commands to these and brakes past them."""
    rows: list[dict[str, object]] = []
    for j, name in enumerate(names):
        lower, upper = (float(x) for x in joint_limits[j])
        ranged = bool(np.isfinite(lower) and np.isfinite(upper))
        rows.append({"joint": name, "unit": "m" if slide[j] else "rad", "effort": float(effort[j]),
                     "velocity": float(velocity[j]) if velocity[j] > 0 else None,
                     "lower": lower if ranged else None, "upper": upper if ranged else None})
    return rows


def inertia_matrix(dyn_row: np.ndarray) -> np.ndarray:
    """The symmetric 3x3 inertia about the COM from one `dyn` row (link frame i)."""
    _, _, _, _, ixx, iyy, izz, ixy, ixz, iyz, _ = dyn_row
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


def dh_link_transform(dh_row: np.ndarray) -> np.ndarray:
    """The fixed part Tz(d) Tx(a) Rx(alpha) of one DH row: link frame i seen from the joint-i frame.

    The joint-i frame is frame i-1 turned by Rz(q_i + theta_offset_i); a body that moves with joint i
    is placed there, so its hinge is its own z axis and its angle is q_i.
    """
    _, d, a, alpha = dh_row
    ca, sa = np.cos(alpha), np.sin(alpha)
    return np.array(
        [
            [1.0, 0.0, 0.0, a],
            [0.0, ca, -sa, 0.0],
            [0.0, sa, ca, d],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0, 0.0], [s, c, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
