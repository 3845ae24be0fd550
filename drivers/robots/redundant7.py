"""A 7-DOF redundant S-R-S arm like the KUKA LBR iiwa 14 R820, for the simulated plant.

The TR's redundant-arm work used a 7-DOF Robotics Research arm; no complete public dynamic model
of it exists, so this arm is its modern anthropomorphic counterpart: a spherical shoulder (joints
1-3), an elbow (4) and a spherical wrist (5-7), all offsets a_i = 0, one redundant DOF (the elbow
may swing about the shoulder-wrist line with the hand held still).

Sources:
- Kinematics: the iiwa 14 R820's standard DH (d1 = 0.36, d3 = 0.42, d5 = 0.40, d7 = 0.126 m to the
  flange; alphas -+ pi/2), as in the KUKA data sheet's dimensions and Drake's `iiwa14_no_collision.urdf`,
  whose joint origins give the same axis lines (checked: every URDF joint axis at the zero pose is
  the DH z axis with the same sense, so the joint senses are KUKA's).
- Link masses, COMs and inertias: Drake's `iiwa14_no_collision.urdf` (RobotLocomotion/drake,
  manipulation/models/iiwa_description; the MuJoCo Menagerie iiwa 14 is derived from the same
  data), moved from the URDF link frames into DH link frame i. Each URDF link frame differs from
  DH frame i by quarter turns and a shift along the joint axis, so the diagonal URDF inertias
  stay diagonal (permuted) and each COM is the URDF COM permuted, sign-changed and shifted.
- Joint limits (±170, ±120, ±170, ±120, ±170, ±120, ±175 deg) and peak torques (320, 320, 176,
  176, 110, 40, 40 N m): KUKA's LBR iiwa brochure, as quoted in Drake's iiwa_description README.
- Speed limits (85, 85, 100, 75, 130, 135, 135 deg/s): KUKA's LBR iiwa 14 R820 data sheet, the
  `<limit velocity>` of Drake's iiwa14 URDF.
- Joint damping 0.5 N m s/rad on every joint: Drake's URDF `<dynamics damping>`.
- Armature: ESTIMATED (KUKA publishes no rotor data). Gear ratio 160 (the usual harmonic-drive
  ratio of such joints) and rotor inertias of 30, 15, 7.5 and 4 e-6 kg m² for the four motor
  sizes the torque limits suggest: 0.77 kg m² at the shoulder down to 0.10 at the wrist, the same
  order as the PUMA's 0.2-2.3 and well below the links' inertia about the proximal joints.
"""

from __future__ import annotations

import numpy as np

from drivers.robots.description import RobotDescription

_DEG = np.pi / 180.0

#: (theta_offset, d, a, alpha), standard DH.
_DH = np.array(
    [
        [0.0, 0.36, 0.0, -np.pi / 2],
        [0.0, 0.0, 0.0, np.pi / 2],
        [0.0, 0.42, 0.0, np.pi / 2],
        [0.0, 0.0, 0.0, -np.pi / 2],
        [0.0, 0.40, 0.0, -np.pi / 2],
        [0.0, 0.0, 0.0, np.pi / 2],
        [0.0, 0.126, 0.0, 0.0],
    ]
)

#: kg, Drake's values (its comments give KUKA's CAD values, lighter for the distal links).
_MASS = np.array([5.76, 6.35, 3.5, 3.5, 3.5, 1.8, 1.2])

#: COM in DH link frame i (m): Drake's URDF COMs, moved as the module docstring says.
_COM = np.array(
    [
        [0.0, 0.0825, -0.03],
        [-0.0003, 0.042, 0.059],
        [0.0, -0.0855, -0.03],
        [0.0, -0.034, 0.067],
        [-0.0001, 0.1395, -0.021],
        [0.0, 0.0004, 0.0006],
        [0.0, 0.0, -0.025],
    ]
)

#: Inertia about the COM in DH link frame i (kg m²): Ixx, Iyy, Izz (products are zero).
#: Drake's diagonal inertias permuted into the DH axes; all satisfy the triangle inequality.
_INERTIA = np.array(
    [
        [0.033, 0.0123, 0.0333],
        [0.0305, 0.011, 0.0304],
        [0.025, 0.0076, 0.0238],
        [0.017, 0.006, 0.0164],
        [0.01, 0.00449, 0.0087],
        [0.0049, 0.0036, 0.0047],
        [0.001, 0.001, 0.001],
    ]
)

_GEAR = 160.0
#: ESTIMATED rotor inertias (kg m², motor side); armature = Jm G².
_JM = np.array([30e-6, 30e-6, 15e-6, 15e-6, 7.5e-6, 4e-6, 4e-6])

_DAMPING = np.full(7, 0.5)

_JOINT_LIMITS = np.array([[-170, 170], [-120, 120], [-170, 170], [-120, 120], [-170, 170], [-120, 120], [-175, 175]]) * _DEG

_TORQUE_LIMITS = np.array([320.0, 320.0, 176.0, 176.0, 110.0, 40.0, 40.0])

_VELOCITY_LIMITS = np.array([85.0, 85.0, 100.0, 75.0, 130.0, 135.0, 135.0]) * _DEG

#: Home pose: shoulder pitched 30 deg forward, elbow bent 60 deg back, wrist pitched 60 deg, so
#: the shoulder, elbow and wrist are all away from their singularities (q2, q4, q6 != 0 keeps
#: joints 1 and 3, the upper arm and forearm, and joints 5 and 7 from lining up).
_Q0 = np.array([0.0, 30.0, 0.0, -60.0, 0.0, 60.0, 0.0]) * _DEG


def redundant7() -> RobotDescription:
    """The iiwa-like 7-DOF arm, braked at `_Q0` (a non-singular 'ready' pose)."""
    dyn = np.zeros((7, 11))
    dyn[:, 0] = _MASS
    dyn[:, 1:4] = _COM
    dyn[:, 4:7] = _INERTIA
    dyn[:, 10] = _JM * _GEAR**2
    return RobotDescription(
        name="redundant7",
        ndof=7,
        dh=_DH,
        dyn=dyn,
        damping=_DAMPING,
        joint_limits=_JOINT_LIMITS,
        torque_limits=_TORQUE_LIMITS,
        q0=_Q0,
        velocity_limits=_VELOCITY_LIMITS,
    )
