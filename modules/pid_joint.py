"""PID joint position controller (TR Figure 8), with optional gravity feed-forward.

tau_u = kp (q_r - q_m) + kd (qd_r - qd_m) + ki ∫(q_r - q_m) dt + g(q_m) + handover

The gains are given raw (kp, kd, ki: one for every joint or one per joint) or as a bandwidth:
`bandwidth: 30` (rad/s), `damping: 1.0` and optionally `integral_time` (s) make each joint's
kp = I w², kd = 2 ζ I w, ki = kp / integral_time with I the joint's heaviest reflected inertia over
the workspace, or a lighter one where gains that stiff would leave a light pose poorly damped at
this task's period (`pbo_runtime.inertia_range`, `arm_gains`: what `pbo robot --bandwidth` prints):
the same response on a light wrist as on a heavy shoulder. `pbo check` says the gains and whether each loop is stable.

The gravity term comes from Pinocchio, built in `init` from the robot's in-consts ARM and EE,
so the same module drives whatever arm the robot interface reports.

On `on`, with feed-forward, the integral starts at zero, not from the torque in the table: that
torque holds the previous controller's proportional and derivative terms of a moment ago, which
in the integral would stay for kp / ki seconds. If that torque drives the arm now (the actuators
are not held), the difference goes to a handover term that fades out with
`HANDOVER_TIME_CONSTANT`: the first output equals it, and none of it stays. If it does not (a
restarted controller: the robot interface held the arm on its brakes meanwhile), the PID starts
from the measured state alone. Without feed-forward the integral carries the load, so it takes
the difference over itself (its joints with integral action only). While the actuators are held
(`actuators_held`: a stopped plant, a stale torque, the table lock held) nothing is integrated:
the arm does not answer, and q_m may stand still.

The cycle calls its ufuncs with the output positional and arrays for operands, on its ports'
arrays taken once in `init` (each `out=`, Python number or port lookup costs a call more than a
six-element operation does).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy import add, multiply, subtract

from modules._ufuncs import clip
from pbo_runtime import Arm, InConst, InVar, OutVar, PortBasedObject, Status, arm_gains, arm_model, inertia_range, param

Gain = float | tuple[float, ...]


@dataclass(frozen=True)
class PidJointParams:
    # one gain for every joint, or a list of one per joint (pbo check counts them)
    kp: Gain = param(400.0, at_least=0, at_most=1e6, shape=("NDOF",))  # N m / rad
    kd: Gain = param(40.0, at_least=0, at_most=1e5, shape=("NDOF",))  # N m s / rad
    ki: Gain = param(0.0, at_least=0, at_most=1e6, shape=("NDOF",))  # N m / (rad s)
    # a bandwidth instead of the gains: > 0 makes kp, kd and ki from the arm's inertia (give one or the other)
    bandwidth: float = param(0.0, at_least=0, at_most=1e4)  # rad/s; 0: the raw gains above
    damping: float = param(1.0, above=0, at_most=10)  # damping ratio, with bandwidth
    integral_time: float = param(0.0, at_least=0, at_most=1e4)  # s, with bandwidth: ki = kp / integral_time; 0: no integral
    integral_limit: float = param(50.0, at_least=0, at_most=1e4)  # N m: the integral term never exceeds this (anti-windup)
    gravity_feedforward: bool = True

    def __post_init__(self) -> None:
        for name in ("kp", "kd", "ki"):
            value = getattr(self, name)
            gains = value if isinstance(value, tuple) else (value,)
            if any(g < 0 for g in gains):
                raise ValueError(f"{name} must be >= 0, got: {value}")
        if self.integral_limit < 0:
            raise ValueError(f"integral_limit must be >= 0, got: {self.integral_limit}")


class PidJoint(PortBasedObject):
    """PID joint position controller. The cycle allocates no arrays of its own; the gravity
    term is Pinocchio's `computeGeneralizedGravity` on a model built once in `init`."""

    Params = PidJointParams
    # pbo set pid kp 300: the gains change between two cycles. A bandwidth is not tunable: making
    # gains from it searches the inertia range, too long between two cycles (pbo replace changes it)
    TUNABLE = ("kp", "kd", "ki")

    ndof = InConst("NDOF", dtype="int32")
    arm_table = InConst("ARM", shape=("NDOF", Arm.WIDTH), doc="the arm's joint table (pbo_runtime.ARM_COLUMNS)")
    end_effector = InConst("EE", shape=(Arm.EE_WIDTH,), doc="where the end effector is (pbo_runtime.EE_COLUMNS)")
    q_r = InVar("q_r", shape=("NDOF",), doc="reference joint position, rad")
    qd_r = InVar("qd_r", shape=("NDOF",), doc="reference joint velocity, rad/s")
    q_m = InVar("q_m", shape=("NDOF",), doc="measured joint position, rad")
    qd_m = InVar("qd_m", shape=("NDOF",), doc="measured joint velocity, rad/s")
    tau = OutVar("tau_u", shape=("NDOF",), doc="joint torque command, N m")

    HANDOVER_TIME_CONSTANT = 0.02  # s: the previous controller's torque beyond this one's fades out this fast

    def init(self, params: PidJointParams) -> None:
        n = int(self.ndof)
        self._kp, self._kd, self._ki = self._all_gains(params, n)
        self._limit = params.integral_limit
        self._integral_low, self._integral_high = np.full(n, -self._limit), np.full(n, self._limit)
        self._dt = np.full(n, self.period)
        self._error = np.zeros(n)
        self._term = np.zeros(n)
        self._integral = np.zeros(n)  # the integral term itself, N m
        self._handover = np.zeros(n)  # the previous controller's torque beyond this one's, fading out, N m
        self._previous = np.zeros(n)  # what the previous controller left in the table, read at `on`
        self._fade = float(np.exp(-self.period / self.HANDOVER_TIME_CONSTANT))
        # cycles until the handover is down to a billionth of itself, then it is dropped
        self._fade_cycles = int(np.ceil(np.log(1e-9) / np.log(self._fade))) if self._fade > 0.0 else 1
        self._fading = 0  # cycles of the handover left
        self._taking_over = False  # the first cycle after `on` takes the previous controller's torque over
        # the ports' arrays, the task's for its life
        self._q_r, self._qd_r, self._q_m, self._qd_m, self._tau = self.q_r, self.qd_r, self.q_m, self.qd_m, self.tau
        self._gravity = None
        if params.gravity_feedforward:
            import pinocchio

            model = arm_model(self.arm_table, self.end_effector)
            self._gravity = functools.partial(pinocchio.computeGeneralizedGravity, model, model.createData())

    @staticmethod
    def _gains(name: str, value: Gain, n: int) -> np.ndarray:
        gains = np.asarray(value, dtype=float)
        if gains.ndim == 1 and gains.size != n:
            raise ValueError(f"{name} must have one gain or NDOF = {n} gains, got: {gains.size}")
        return np.broadcast_to(gains, (n,)).copy()

    def _all_gains(self, params: PidJointParams, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(kp, kd, ki) per joint: the raw gains, or those of the bandwidth at the arm's inertia."""
        if params.bandwidth > 0:
            inertia = inertia_range(self.arm_table, self.end_effector)
            kp, kd, ki, _ = arm_gains(inertia, params.bandwidth, params.damping, params.integral_time, self.period)
            return kp, kd, ki
        return self._gains("kp", params.kp, n), self._gains("kd", params.kd, n), self._gains("ki", params.ki, n)

    @property
    def gains(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(kp, kd, ki) per joint, as the cycle uses them."""
        return self._kp, self._kd, self._ki

    def tune(self, params: PidJointParams) -> None:
        kp, kd, ki = self._all_gains(params, self._kp.size)
        np.copyto(self._kp, kp)
        np.copyto(self._kd, kd)
        np.copyto(self._ki, ki)
        np.copyto(self._integral, 0.0, where=self._ki == 0)  # no integral action left: it would never decay

    def on(self) -> None:
        previous = self._previous
        np.copyto(previous, self._tau)  # what the previous controller left in the table (read before `on`)
        self._handover[:] = 0.0
        self._fading = 0
        self._integral[:] = 0.0
        # nothing commanded yet, or held on the brakes (a restart: what the dead controller left is
        # not what the arm feels): its own torque from the start, nothing taken over
        # (count_nonzero: a plain loop, where np.any sets up a whole reduction at the switch's boundary)
        self._taking_over = bool(np.count_nonzero(previous)) and not self.actuators_held
        if not self._taking_over:
            self._compute()
        # Else tau stays the previous controller's torque until the first cycle, at the same
        # boundary, takes it over: computing it here would only lengthen the switch that turns
        # this task on, before any cycle of the boundary runs.

    def cycle(self) -> Status:
        integrating = not self.actuators_held  # the arm answers: integrate
        if integrating:
            error, term, integral = self._error, self._term, self._integral
            subtract(self._q_r, self._q_m, error)
            multiply(error, self._ki, term)
            multiply(term, self._dt, term)
            add(integral, term, integral)
            clip(integral, self._integral_low, self._integral_high, integral)
        if self._fading:
            self._fading -= 1
            np.multiply(self._handover, self._fade if self._fading else 0.0, out=self._handover)
        self._compute(error_ready=integrating)
        if self._taking_over:
            self._take_over()
        return Status.CONTINUE

    def _take_over(self) -> None:
        """The first cycle after `on` takes over the previous controller's torque: its output is that
        torque, and the difference from this controller's own fades out (feed-forward) or is carried
        by the integral (without: the load is the integral's, on the joints that have one)."""
        self._taking_over = False
        previous, tau = self._previous, self.tau
        if self._gravity is None:
            carried, change = self._term, self._error  # (free after `_compute`)
            np.subtract(previous, tau, out=carried)
            np.add(carried, self._integral, out=carried)
            np.clip(carried, -self._limit, self._limit, out=carried)
            np.copyto(carried, 0.0, where=self._ki == 0)
            np.subtract(carried, self._integral, out=change)
            np.copyto(self._integral, carried)
            np.add(tau, change, out=tau)
        elif not self.actuators_held:  # that torque drives the arm now: take it over, fading
            np.subtract(previous, tau, out=self._handover)
            self._fading = self._fade_cycles
            if self._fading:
                np.add(tau, self._handover, out=tau)

    def _compute(self, error_ready: bool = False) -> None:
        """tau = kp e + kd ed + integral + handover (+ g(q_m) with feed-forward). `error_ready`: the
        cycle's integration left e = q_r - q_m in `_error` already."""
        tau, term, error, q_m = self._tau, self._term, self._error, self._q_m
        if not error_ready:
            subtract(self._q_r, q_m, error)
        multiply(self._kp, error, tau)
        subtract(self._qd_r, self._qd_m, error)
        multiply(self._kd, error, term)
        add(tau, term, tau)
        if self._gravity is not None:
            add(tau, self._gravity(q_m), tau)
        add(tau, self._integral, tau)
        if self._fading:
            add(tau, self._handover, tau)
