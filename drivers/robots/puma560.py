"""A PUMA 560-like arm from the classic published parameters, for the simulated plant.

Sources: P. Corke, Robotics Toolbox `mdl_puma560` (standard DH), which takes kinematics and
dynamics from Armstrong, Khatib and Burdick (1986) "The explicit dynamic model and inertial
parameters of the PUMA 560 arm", and motor data (Jm, G, B) from Corke and Armstrong-Hélouvry (1995).
Values that a simulator cannot integrate are changed minimally; each change is marked CHANGED.
"""

from __future__ import annotations

import numpy as np

from drivers.robots.description import RobotDescription

_DEG = np.pi / 180.0

#: (theta_offset, d, a, alpha), standard DH, as in Corke's mdl_puma560.
_DH = np.array(
    [
        [0.0, 0.0, 0.0, np.pi / 2],
        [0.0, 0.0, 0.4318, 0.0],
        [0.0, 0.15005, 0.0203, -np.pi / 2],
        [0.0, 0.4318, 0.0, np.pi / 2],
        [0.0, 0.0, 0.0, -np.pi / 2],
        [0.0, 0.0, 0.0, 0.0],
    ]
)

_MASS = np.array(
    [
        # CHANGED: Corke gives link 1 mass 0 (its COM is on the joint-1 axis, so the mass never
        # enters the arm's dynamics); MuJoCo refuses a moving body without mass. 1 kg is as
        # invisible as 0 to every joint torque, because the base is fixed and r1 = 0.
        1.0,
        17.4,
        4.8,
        0.82,
        0.34,
        0.09,
    ]
)

#: COM in link frame i (m), Corke's `r`.
_COM = np.array(
    [
        [0.0, 0.0, 0.0],
        [-0.3638, 0.006, 0.2275],
        [-0.0203, -0.0141, 0.070],
        [0.0, 0.019, 0.0],
        [0.0, 0.0, 0.0],
        [0.0, 0.0, 0.032],
    ]
)

#: Inertia about the COM in link frame i (kg m²): Ixx, Iyy, Izz (products are zero).
_INERTIA = np.array(
    [
        # CHANGED: Corke gives [0, 0.35, 0], which is no rigid body (Ixx + Izz < Iyy). Link 1 only
        # ever turns about its y axis (the base z axis), so only Iyy = 0.35 acts; Ixx = Izz =
        # 0.175 (a flat disc about y) makes it physical without changing any joint torque.
        [0.175, 0.35, 0.175],
        [0.13, 0.524, 0.539],
        # CHANGED: Corke gives Izz = 0.0125, which breaks Ixx + Izz >= Iyy (0.0785 < 0.086).
        # Izz is the forearm's inertia about its own long axis, the smallest and least
        # certain; raised to 0.0205 (just past equality). Iyy, about the elbow axis, is kept.
        [0.066, 0.086, 0.0205],
        [1.8e-3, 1.3e-3, 1.8e-3],
        [0.3e-3, 0.4e-3, 0.3e-3],
        [0.15e-3, 0.15e-3, 0.04e-3],
    ]
)

#: Motor rotor inertia (kg m²) and gear ratio; armature = Jm G² is the rotor seen at the joint.
_JM = np.array([200e-6, 200e-6, 200e-6, 33e-6, 33e-6, 33e-6])
_GEAR = np.array([-62.6111, 107.815, -53.7063, 76.0364, 71.923, 76.686])

#: Motor viscous friction (N m s/rad, motor side), Corke's `B`. Damping = B G² is the same
#: friction seen at the joint: 5.8, 9.5, 4.0, 0.41, 0.43, 0.22 N m s/rad, modest next to the
#: torque limits; Coulomb friction (Corke's `Tc`) is left out.
_B_MOTOR = np.array([1.48e-3, 0.817e-3, 1.38e-3, 71.2e-6, 82.6e-6, 36.7e-6])

#: Corke's `qlim`.
_JOINT_LIMITS = np.array([[-160, 160], [-45, 225], [-225, 45], [-110, 170], [-100, 100], [-266, 266]]) * _DEG

#: Peak joint torques (N m) as commonly cited for the PUMA 560 (e.g. in time-optimal
#: trajectory studies); Corke's model gives none. Gravity at the stretched-out pose needs ~37 N m
#: at joint 2, well inside.
_TORQUE_LIMITS = np.array([97.6, 186.4, 89.4, 24.2, 20.1, 21.3])


def puma560() -> RobotDescription:
    """The PUMA 560-like arm; home pose is Corke's `qz` (all zero: upper arm level, forearm up)."""
    dyn = np.zeros((6, 11))
    dyn[:, 0] = _MASS
    dyn[:, 1:4] = _COM
    dyn[:, 4:7] = _INERTIA
    dyn[:, 10] = _JM * _GEAR**2
    return RobotDescription(
        name="puma560",
        ndof=6,
        dh=_DH,
        dyn=dyn,
        damping=_B_MOTOR * _GEAR**2,
        joint_limits=_JOINT_LIMITS,
        torque_limits=_TORQUE_LIMITS,
        q0=np.zeros(6),
    )
