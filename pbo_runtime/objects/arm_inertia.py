"""Each joint's reflected inertia over the arm's workspace: the range a joint's loop must be stable over.

A joint's reflected inertia is its diagonal element of the joint-space mass matrix (Pinocchio's
`crba`, armature included): the inertia the joint's motor drives with the other joints held. It
changes with the pose of the joints beyond it, often twenty-fold on a long arm. With the other
joints free it is lighter still, 1 / (M⁻¹)_jj: much lighter where two joints turn about nearly
the same axis (a Panda's first and third joints, stretched upright). A loop must be stable down
to that, so the loop analysis takes its range from there to the heaviest diagonal. The range is taken
over seeded samples of poses within the joints' position limits (a joint without a range: a whole
turn), plus the zero pose, so the same arm always gives the same range.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from pbo_runtime.objects.arm import Arm, arm_model, check_arm
from pbo_runtime.objects.joint_loop import design_gains
from pbo_runtime.objects.waits import sleep_while_cycling

#: Poses sampled over the workspace, and their seed.
SAMPLES = 512
SEED = 36


@dataclass(frozen=True)
class InertiaRange:
    """Per joint: the lightest and heaviest reflected inertia found, and the poses where (kg m², kg)."""

    low: np.ndarray  # (n,)
    high: np.ndarray  # (n,)
    low_pose: np.ndarray  # (n, n): row j is the pose where joint j is lightest
    high_pose: np.ndarray  # (n, n)
    viscous: np.ndarray  # (n,) each joint's viscous friction (ARM's damping), N m s/rad: it damps the loop too
    coupled_low: np.ndarray  # (n,) the lightest 1 / (M⁻¹)_jj found: the joint with the others free


def sample_poses(arm: np.ndarray, count: int = SAMPLES, seed: int = SEED) -> np.ndarray:
    """`count` poses (count, n) uniform within the position limits, the zero pose (clipped into them) first."""
    limited = arm[:, Arm.LIMITED] > 0
    low = np.where(limited, arm[:, Arm.Q_MIN], -math.pi)
    high = np.where(limited, arm[:, Arm.Q_MAX], math.pi)
    poses = np.random.default_rng(seed).uniform(low, high, size=(count, arm.shape[0]))
    poses[0] = np.clip(0.0, low, high)
    return poses


def inertia_range(arm: Any, ee: Any, count: int = SAMPLES, seed: int = SEED) -> InertiaRange:
    """Each joint's reflected inertia range over `count` seeded poses (Pinocchio's `crba`). The same
    arm gives the same range: it is computed once a machine and kept on disk (`result_cache`), read
    once a process (a check, a controller's init)."""
    arm, ee = check_arm(arm, ee)
    return _inertia_range(arm.tobytes(), arm.shape, ee.tobytes(), count, seed)


@functools.lru_cache(maxsize=16)
def _inertia_range(arm_bytes: bytes, shape: tuple[int, ...], ee_bytes: bytes, count: int, seed: int) -> InertiaRange:
    """The range kept on disk by an earlier process (`result_cache`), else computed with Pinocchio and kept."""
    from pbo_runtime.objects import arm as arm_module
    from pbo_runtime.objects import result_cache

    name = result_cache.fingerprint("inertia range", arm_bytes, repr(shape), ee_bytes, repr((count, seed)),
                                    sources=(__file__, arm_module.__file__), libraries=("pinocchio",))
    kept = result_cache.cached_arrays(name, lambda: vars(_computed_range(arm_bytes, shape, ee_bytes, count, seed)))
    keys = ("low", "high", "low_pose", "high_pose", "viscous", "coupled_low")
    found = InertiaRange(**{key: np.array(kept[key]) for key in keys})
    for values in vars(found).values():
        values.setflags(write=False)  # shared by every caller of the cache
    return found


def _computed_range(arm_bytes: bytes, shape: tuple[int, ...], ee_bytes: bytes, count: int, seed: int) -> InertiaRange:
    import pinocchio

    arm = np.frombuffer(arm_bytes).reshape(shape)
    model = arm_model(arm, np.frombuffer(ee_bytes))
    data = model.createData()
    poses = sample_poses(arm, count, seed)
    n = arm.shape[0]
    matrices = np.empty((count, n, n))
    for k, q in enumerate(poses):
        matrices[k] = pinocchio.crba(model, data, q)  # the upper triangle is filled
        if k % 64 == 63:
            sleep_while_cycling(0)  # in a live spawn's init, the RTPU's due cycles run meanwhile
    upper = np.triu(matrices)
    full = upper + np.transpose(np.triu(matrices, 1), (0, 2, 1))
    diagonals = np.diagonal(full, axis1=1, axis2=2)  # (count, n)
    coupled = 1.0 / np.diagonal(np.linalg.inv(full), axis1=1, axis2=2)
    lightest, heaviest = np.argmin(diagonals, axis=0), np.argmax(diagonals, axis=0)
    joints = np.arange(n)
    low, high = diagonals[lightest, joints].copy(), diagonals[heaviest, joints].copy()
    return InertiaRange(low, high, poses[lightest], poses[heaviest], arm[:, Arm.DAMPING].copy(),
                        np.minimum(coupled.min(axis=0), low))


def arm_gains(inertia: InertiaRange, bandwidth: float, damping: float = 1.0, integral_time: float = 0.0,
              period: float = 0.001) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(kp, kd, ki, design inertia) per joint for a loop of `bandwidth` rad/s and `damping`, sampled
    at `period` with one period of delay (`joint_loop.design_gains`): made for each joint's heaviest
    pose unless that would leave a lighter one (down to `coupled_low`) poorly damped."""
    made = [design_gains(float(low), float(high), bandwidth, damping, integral_time, period, viscous=float(b))
            for low, high, b in zip(inertia.coupled_low, inertia.high, inertia.viscous, strict=True)]
    return (np.array([g.kp for g, _ in made]), np.array([g.kd for g, _ in made]), np.array([g.ki for g, _ in made]),
            np.array([design for _, design in made]))
