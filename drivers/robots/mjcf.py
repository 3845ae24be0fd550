"""MuJoCo MJCF for a `RobotDescription`: the plant's physics, generated so it matches the DH model.

Body i moves with joint i and its frame is the joint-i frame: DH frame i-1 turned by
Rz(q_i + theta_offset_i). Its hinge is therefore its own z axis through its origin, MuJoCo's joint
angle is exactly the DH variable q_i, and body i sits in body i-1 at the fixed transform
Tz(d_{i-1}) Tx(a_{i-1}) Rx(alpha_{i-1}) Rz(theta_offset_i). Link i's inertial data, given in DH
frame i, is moved into body i by Tz(d_i) Tx(a_i) Rx(alpha_i).

Integrator: `implicitfast`. Joint damping (and armature, through the mass matrix) is integrated
implicitly, so the step stays stable whatever the ratio of damping to the light wrist links'
inertia; it costs one dynamics evaluation per step where RK4 costs four, which matters for a plant
stepping at 1 kHz in real time. RK4's extra accuracy buys nothing here: a controller's PD torques
arrive held constant over each step (zero-order hold), so their stiffness is bounded by the
sampling, not by the integrator.

Site `ee` is the tool frame (DH frame n), the end effector. The plant adds its own parts (the wrist
force/torque sensor, the camera's target) to this model as it does to any robot's
(`drivers.robots.plant_model`). Each joint's torque limit is its `actuatorfrcrange`.
"""

from __future__ import annotations

import mujoco
import numpy as np

from drivers.robots.description import RobotDescription, dh_link_transform, inertia_matrix, rot_z

_LINK_RADIUS = 0.04  # capsule radius for looks only (m)


def _num(values: np.ndarray | float) -> str:
    # round-off of cos(pi/2) (1e-17) would only clutter the text; it is not data
    return " ".join(f"{0.0 if abs(v) < 1e-14 else float(v):.17g}" for v in np.atleast_1d(values))


def _quat(rotation: np.ndarray) -> np.ndarray:
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(rotation, dtype=np.float64).reshape(9))
    return quat


def _body_placement(desc: RobotDescription, i: int) -> np.ndarray:
    """Body i (0-based) in its parent: the previous link's fixed DH transform, then this joint's offset."""
    parent_link = dh_link_transform(desc.dh[i - 1]) if i > 0 else np.eye(4)
    placement: np.ndarray = parent_link @ rot_z(desc.dh[i, 0])
    return placement


def _inertial_xml(desc: RobotDescription, i: int) -> str:
    link = dh_link_transform(desc.dh[i])
    rotation, offset = link[:3, :3], link[:3, 3]
    row = desc.dyn[i]
    com = rotation @ row[1:4] + offset
    inertia = rotation @ inertia_matrix(row) @ rotation.T
    full = [inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2]]
    return f'<inertial pos="{_num(com)}" mass="{_num(row[0])}" fullinertia="{_num(np.array(full))}"/>'


def _geoms_xml(desc: RobotDescription, i: int) -> list[str]:
    """Capsules along the link's d (joint z) and a (then x) offsets; they never collide."""
    _, d, a, _ = desc.dh[i]
    common = f'size="{_LINK_RADIUS}" contype="0" conaffinity="0" rgba="0.7 0.7 0.75 1"'
    geoms = [f'<geom name="link{i + 1}_joint" type="sphere" {common}/>']
    if abs(d) > 1e-9:
        geoms.append(f'<geom name="link{i + 1}_d" type="capsule" fromto="0 0 0 0 0 {_num(d)}" {common}/>')
    if abs(a) > 1e-9:
        fromto = f"0 0 {_num(d)} {_num(a)} 0 {_num(d)}"
        geoms.append(f'<geom name="link{i + 1}_a" type="capsule" fromto="{fromto}" {common}/>')
    return geoms


def to_mjcf(desc: RobotDescription, timestep: float) -> str:
    """The MJCF text of `desc` with `<option timestep=...>`: bodies `link<i>`, hinges `joint<i>`, site `ee`."""
    if not timestep > 0:
        raise ValueError(f"timestep must be > 0, got: {timestep}")
    lines = [
        f'<mujoco model="{desc.name}">',
        '  <compiler angle="radian" inertiafromgeom="false" autolimits="true"/>',
        f'  <option timestep="{_num(timestep)}" integrator="implicitfast" gravity="0 0 -9.81"/>',
        "  <worldbody>",
        '    <geom name="pedestal" type="cylinder" size="0.08 0.3" pos="0 0 -0.3" contype="0" conaffinity="0"'
        ' rgba="0.3 0.3 0.35 1"/>',
    ]
    closers = []
    for i in range(desc.ndof):
        indent = "    " + "  " * i
        placement = _body_placement(desc, i)
        lines.append(
            f'{indent}<body name="link{i + 1}" pos="{_num(placement[:3, 3])}" quat="{_num(_quat(placement[:3, :3]))}">'
        )
        inner = indent + "  "
        lower, upper = desc.joint_limits[i]
        lines.append(
            f'{inner}<joint name="joint{i + 1}" type="hinge" pos="0 0 0" axis="0 0 1" '
            f'range="{_num(lower)} {_num(upper)}" armature="{_num(desc.dyn[i, 10])}" '
            f'damping="{_num(desc.damping[i])}" limited="true" '
            f'actuatorfrcrange="{_num(-desc.torque_limits[i])} {_num(desc.torque_limits[i])}"/>'
        )
        lines.append(inner + _inertial_xml(desc, i))
        lines.extend(inner + g for g in _geoms_xml(desc, i))
        closers.append(f"{indent}</body>")
    tool = dh_link_transform(desc.dh[-1])
    indent = "    " + "  " * desc.ndof
    site = f'pos="{_num(tool[:3, 3])}" quat="{_num(_quat(tool[:3, :3]))}"'
    lines.append(f'{indent}<site name="ee" {site} size="0.01"/>')
    lines.extend(reversed(closers))
    lines += [
        "  </worldbody>",
        "</mujoco>",
        "",
    ]
    return "\n".join(lines)
