"""The simulated arm itself: a MuJoCo model of a robot (registered, or from a URDF or MJCF file),
stepped by a plant host process.

The plant owns the register segment (see `registers`): it publishes the measured state after every
step and applies whatever the driver last commanded, in torque or position mode (`MODE`). It starts
with the brakes engaged so the arm does not fall before a controller is on. It does no real-time
pacing: the host calls `step()` once per `timestep` of wall time (or as fast as it likes, in tests).
Options: `ee` (the end effector: a link or site of the robot's file), `q0`, `torque_limits` and
`velocity_limits` (where the file gives none, or lower than it gives: never higher), `joint_limits`
(a narrower range than the file's), `target` (a moving marker for the camera),
`wrist_wrench` (a contact), `adc_noise` and `seed` (the I/O boards that carry the wrist
force/torque sensor), `command_timeout` (the drive's watchdog: with the brakes released and no
new command for that long, the arm holds on its brakes until one comes).

docs/plant.md says how the position servo is designed (gains, braking curve) and what each option
does.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy import copyto

from drivers.force_torque import models as ft_models
from drivers.mujoco_arm.registers import (
    ADC_CHANNELS,
    MAGIC,
    MODE_POSITION,
    MODE_TORQUE,
    VOLTS_PER_COUNT,
    W_BOARD_SEQ,
    W_BOARD_STEP,
    W_BRAKE,
    W_CMD_SEQ,
    W_MAGIC,
    W_MODE,
    W_PLANT_PID,
    W_SIM_TIME,
    W_STATE_SEQ,
    W_STEP_COUNT,
    W_TARGET,
    W_TIMESTEP,
    create_registers,
)
from pbo_runtime import ROBOT_OPTIONS, param, unlink_quietly

if TYPE_CHECKING:
    import mujoco

    from drivers.robots.plant_model import PlantRobot

# Simulated seconds without a new command after which the arm holds on its brakes, as a drive's
# watchdog does when its controller stops (a stopped robot interface cannot engage them itself)
COMMAND_TIMEOUT = 0.05
# numpy's clip ufunc without np.clip's Python layers
_CLIP: Any = getattr(getattr(getattr(np, "_core", None), "umath", None), "clip", np.clip)
_LOOPBACK_DAC, _LOOPBACK_ADC = slice(0, 2), slice(6, 8)  # DAC channels 0-1 joined to ADC 6-7 by the loopback cable
_TARGET_OPTIONS = ("center", "radius", "period", "phase", "orientation")
# A driver's command write takes about a microsecond; if the seqlock is still odd after this many
# looks the driver was preempted (or died) mid-write, and the plant keeps the previous command
# rather than wait on it.
_COMMAND_READ_TRIES = 64

#: Position servo: -3 dB bandwidth of each critically damped joint loop, Hz.
SERVO_BANDWIDTH_HZ = 25.0
# A critically damped loop is 3 dB down at w_n sqrt(sqrt(2) - 1) = 0.644 w_n.
_SERVO_OMEGA = 2 * np.pi * SERVO_BANDWIDTH_HZ / np.sqrt(np.sqrt(2.0) - 1.0)
# The servo's torque is held over a step: keep w_n * timestep this small on slow plants.
_SERVO_MAX_OMEGA_DT = 0.25
# Share of a joint's torque limit the servo plans to brake with (the rest covers gravity and
# the pose-dependent inertia it does not model).
_SERVO_BRAKING_SHARE = 0.5


_INT16_MIN, _INT16_MAX = -32768.0, 32767.0  # an ADC's counts
_PER_JOINT = {"shape": ("NDOF",)}  # a list with one value per joint of the robot


@dataclass(frozen=True)
class MujocoArmPlantOptions:
    """The plant's options (the `plant:` keys besides type, model and timestep), declared as a module's
    parameters are, so `pbo check` checks their names, types and lengths before anything runs.

    The robot options (ee, q0, torque_limits, velocity_limits, joint_limits) are checked against the robot itself
    too, when it is loaded (`describe_robot`)."""

    ee: str | None = None  # the end effector: a link or site of the robot's file
    q0: tuple[float, ...] | None = field(default=None, metadata=_PER_JOINT)  # rad: the braked start pose
    torque_limits: tuple[float, ...] | None = field(default=None, metadata=_PER_JOINT)  # N m: tightens the file's, or gives one
    velocity_limits: tuple[float, ...] | None = field(
        default=None, metadata=_PER_JOINT)  # rad/s: tightens the file's, or gives one
    joint_limits: tuple[tuple[float, ...], ...] | None = field(
        default=None, metadata=_PER_JOINT)  # rad: [lower, upper] per joint, within the file's
    target: Mapping[str, Any] | None = None  # a moving target for a camera: {center, radius, period, phase, orientation}
    wrist_wrench: tuple[float, ...] = param((0.0,) * 6, at_least=-1e4, at_most=1e4, shape=(6,))  # N, N m, sensor frame
    adc_noise: float = param(0.0, at_least=0, at_most=10)  # V: standard deviation of each ADC conversion
    seed: int = param(0, at_least=0, at_most=2**32 - 1)  # seeds the ADC noise
    command_timeout: float = param(COMMAND_TIMEOUT, at_least=0, at_most=3600)  # s: the drive's watchdog (0: none)

    def __post_init__(self) -> None:
        _target_options(self.target)
        _wrench_option(self.wrist_wrench)
        adc_noise, seed, command_timeout = self.adc_noise, self.seed, self.command_timeout
        if (
            isinstance(adc_noise, bool)
            or not isinstance(adc_noise, (int, float))
            or not (math.isfinite(adc_noise) and adc_noise >= 0)
        ):
            raise ValueError(f"plant option adc_noise must be a finite number >= 0 (V, standard deviation), got: {adc_noise!r}")
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ValueError(f"plant option seed must be an integer >= 0, got: {seed!r}")
        if isinstance(command_timeout, bool) or not isinstance(command_timeout, (int, float)) or not command_timeout >= 0:
            raise ValueError(
                f"plant option command_timeout must be a number of seconds >= 0 (0: no watchdog), got: {command_timeout!r}"
            )


_OPTIONS = tuple(f.name for f in fields(MujocoArmPlantOptions))


class MujocoArmPlant:
    """One MuJoCo arm behind a register segment named `registers_name`.

    options: `q0` (sequence of ndof floats, rad): the braked start pose; default the robot's home.
    `target` (mapping): a moving target for a camera, `{center: [x, y, z], radius: m, period: s,
    phase: rad, orientation: [rx, ry, rz]}` (center, radius and period required); default none.
    `wrist_wrench` (6 floats, N and N m, sensor frame): a constant external wrench on the tool;
    default none. `adc_noise` (V, >= 0): noise of each ADC conversion; `seed` (int >= 0) seeds it.
    `Options` declares them all. `boards`: False when the subsystem declares no I/O board, whose
    conversions a step then skips (nobody reads them).
    """

    Options = MujocoArmPlantOptions
    DESCRIBED_WITH = ("mujoco",)  # the libraries `describe_robot`'s answer depends on (`pbo check` keeps it by them)

    def __init__(self, registers_name: str, model: str, timestep: float, options: Mapping[str, Any],
                 log_dir: str = "", base_dir: str = ".", boards: bool = True) -> None:
        from drivers.robots.plant_model import load_robot

        route_mujoco_log(log_dir)
        unknown = sorted(set(options) - set(_OPTIONS))
        if unknown:
            raise ValueError(f"unknown mujoco_arm plant option(s) {unknown}; valid options: {', '.join(_OPTIONS)}")
        if not timestep > 0:
            raise ValueError(f"plant timestep must be > 0, got: {timestep}")
        declared = MujocoArmPlantOptions(
            **{k: v for k, v in options.items() if k in ("target", "wrist_wrench", "adc_noise", "seed", "command_timeout")}
        )
        target = _target_options(declared.target)
        wrench = _wrench_option(declared.wrist_wrench)
        adc_noise, seed, command_timeout = declared.adc_noise, declared.seed, declared.command_timeout

        robot = load_robot(model, Path(base_dir), float(timestep), options, target=target is not None)
        n = robot.ndof
        q0 = robot.q0
        self.name = registers_name
        self.timestep = float(timestep)
        self.ndof = n
        self.robot = robot
        self.model = robot.model
        self.data = mujoco.MjData(self.model)
        self.data.qpos[:] = q0
        # MjData's arrays, taken once: each attribute read of the binding costs a fraction of a step
        self._qpos, self._qvel, self._qfrc = self.data.qpos, self.data.qvel, self.data.qfrc_applied
        self.has_target = target is not None
        self._target_pose = np.zeros(6)  # the target's pose at data.time, as published
        if target is not None:
            self._target_center, self._target_radius = target["center"], target["radius"]
            self._target_rate = 2.0 * np.pi / target["period"]
            self._target_phase = target["phase"]
            self._target_pose[3:] = target["orientation"]
            angle = float(np.linalg.norm(target["orientation"]))
            axis = target["orientation"] / angle if angle > 0 else np.array([0.0, 0.0, 1.0])
            mujoco.mju_axisAngle2Quat(self.data.mocap_quat[0], axis, angle)
            self._move_target()
        # The wrist F/T sensor and the boards it is wired to.
        self._ft_body = self.model.body("ft").id
        adr = int(self.model.sensor("ft_force").adr[0])
        self._ft_reading = self.data.sensordata[adr : adr + 6]  # force then torque (ft_torque follows)
        self._wrist_wrench = wrench  # applied, sensor frame
        self._wrench_applied = True  # xfrc_applied may hold a wrench at the sensor (none when it is zero)
        self._wrench = np.zeros(6)  # measured: what the sensor feels, published through the boards
        self._ft_inverse = np.linalg.inv(ft_models.CALIBRATION)
        self._volts = np.zeros(ADC_CHANNELS)
        self._volts_ft, self._volts_looped = self._volts[:6], self._volts[_LOOPBACK_ADC]
        self._counts = np.zeros(ADC_CHANNELS)
        self._noise = np.zeros(ADC_CHANNELS)
        self._adc_noise = float(adc_noise)
        self._rng = np.random.Generator(np.random.PCG64(seed))
        self._a_counts = np.zeros(6)
        self._a_ack = 0  # the last REQUEST vendor A's sensor answered
        self._boards = boards  # a step serves the boards only when the subsystem has one to read them
        self._apply_wrist_wrench()
        mujoco.mj_forward(self.model, self.data)

        self._torque_limits = robot.torque_limits.copy()
        self._torque_floor = -self._torque_limits  # (made once: the step clips every command to both)
        self._q_min = robot.joint_limits[:, 0].copy()
        self._q_max = robot.joint_limits[:, 1].copy()
        self._tau = np.zeros(n)  # last consistent command, preallocated for step()
        self._q_cmd = np.zeros(n)  # last consistent position command
        self._scratch = np.zeros(n)
        self._servo_tau = np.zeros(n)
        self._gravity = np.zeros(n)
        # Gravity for the servo is computed on its own MjData (velocity stays zero there).
        self._gravity_data = mujoco.MjData(self.model)
        self.servo_omega = min(_SERVO_OMEGA, _SERVO_MAX_OMEGA_DT / self.timestep)
        inertia = self._joint_inertia(robot.home)
        self.servo_kp = inertia * self.servo_omega**2
        self.servo_kd = 2.0 * inertia * self.servo_omega
        self.servo_kp.setflags(write=False)
        self.servo_kd.setflags(write=False)
        self._servo_ratio = self.servo_omega / 2.0  # Kp / Kd
        # 2 a per joint, a = the deceleration the servo plans with (half the torque limit)
        self._servo_brake2 = 2.0 * _SERVO_BRAKING_SHARE * self._torque_limits / inertia
        self._brake_pose = q0.copy()
        self._braked = True
        self._steps = 0
        self._time = float(self.data.time)  # the simulated time of the last step (`_publish`)
        self._command_timeout = float(command_timeout)
        self._command_seen = -1  # the command sequence last seen, and the simulated time it changed
        self._command_seen_at = 0.0
        self.watchdog_trips = 0  # times the watchdog held the arm for want of a new command
        self._watchdog_holding = False

        self._shm, self._registers = create_registers(registers_name, n)
        try:
            regs = self._registers
            regs.arm[:] = robot.arm
            regs.ee[:] = robot.ee
            regs.reals[W_TIMESTEP] = self.timestep
            regs.words[W_PLANT_PID] = os.getpid()
            regs.words[W_TARGET] = int(self.has_target)
            self._dac_looped = regs.dac[_LOOPBACK_DAC]
            self._publish()
            regs.pio_in[ft_models.A_STATUS] = ft_models.A_STATUS_POWERED  # vendor A's sensor is on, no reading yet
            self._serve_boards()
            regs.words[W_MAGIC] = MAGIC  # last: a driver refuses the segment until it is complete
        except BaseException:
            self.close()
            raise
        if not boards:  # nobody reads the wrist sensor: each step leaves its computation out (the dynamics do not use it)
            self.model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_SENSOR)

    @staticmethod
    def warm() -> None:
        """Import what a plant imports once made (MuJoCo, the robot loader, numpy's random generators
        for its noise): a fork server calls it, so the plant it forks has them."""
        _import_mujoco()
        import numpy.random  # noqa: F401  (a forked child reseeds its global state: `fork_server_process._child`)

        import drivers.robots.plant_model  # noqa: F401

    @staticmethod
    def describe_robot(model: str, base_dir: str, options: Mapping[str, Any]) -> PlantRobot:
        """The robot a plant of these options would simulate, as `pbo check` sees it; RobotFileError
        (a ValueError whose `key` names the plant key at fault) if it cannot."""
        from drivers.robots.plant_model import load_robot

        return load_robot(model, Path(base_dir), 0.001, {k: v for k, v in options.items() if k in ROBOT_OPTIONS})

    @property
    def sim_time(self) -> float:
        """Simulated time since creation, s."""
        return float(self.data.time)

    @property
    def brakes_engaged(self) -> bool:
        return self._braked

    def _joint_inertia(self, q: np.ndarray) -> np.ndarray:
        """Diagonal of the joint-space mass matrix at pose q (armature included), kg m²."""
        scratch = mujoco.MjData(self.model)
        scratch.qpos[:] = q
        mujoco.mj_forward(self.model, scratch)
        full = np.zeros((self.ndof, self.ndof))
        mujoco.mj_fullM(self.model, scratch, full)
        return np.diag(full).copy()

    def gravity_torque(self, q: np.ndarray, out: np.ndarray) -> np.ndarray:
        """MuJoCo's joint torque holding the arm still at q against gravity (no allocation)."""
        gdata = self._gravity_data
        np.copyto(gdata.qpos, q)
        mujoco.mj_kinematics(self.model, gdata)
        mujoco.mj_comPos(self.model, gdata)
        mujoco.mj_rne(self.model, gdata, 0, out)  # qvel stays 0 in gdata: gravity only
        return out

    def step(self) -> None:
        """Advance the simulation by exactly one timestep and publish the new state."""
        regs = self._registers
        words = regs.words
        data, qpos, qvel = self.data, self._qpos, self._qvel
        if words[W_BRAKE] != 0:
            braked = True
        elif words[W_CMD_SEQ] != self._command_seen:  # a new command (the usual step): the watchdog starts again
            self._command_seen, self._command_seen_at = words[W_CMD_SEQ], self._time
            self._watchdog_holding = False
            braked = False
        else:
            braked = self._command_stale(self._time)
        if braked and not self._braked:
            self._brake_pose[:] = qpos  # brakes grip where the arm is now
        self._braked = braked
        if braked:
            qpos[:] = self._brake_pose
            qvel[:] = 0.0
            self._qfrc[:] = 0.0
        else:
            mode = words[W_MODE]
            if mode == MODE_TORQUE:
                self._read_command(regs.tau, self._tau)
                _CLIP(self._tau, self._torque_floor, self._torque_limits, self._qfrc)  # numpy's clip, NaN kept
            elif mode == MODE_POSITION:
                self._read_command(regs.q_cmd, self._q_cmd)
                self._servo(data)
            else:
                self._qfrc[:] = 0.0
        if self._wrench_applied:
            self._apply_wrist_wrench()
        mujoco.mj_step(self.model, data)
        if braked:
            qpos[:] = self._brake_pose
            qvel[:] = 0.0
        self._steps += 1
        if self.has_target:
            self._move_target()
        self._publish()
        if self._boards:
            self._serve_boards()

    # --- the wrist F/T sensor and the I/O boards --------------------------------------------------

    @property
    def wrist_wrench(self) -> np.ndarray:
        """The external wrench applied at the wrist sensor (N, N m, sensor frame), a copy."""
        return self._wrist_wrench.copy()

    def set_wrist_wrench(self, wrench: Any) -> None:
        """Change the contact from the next step (tests, demos)."""
        self._wrist_wrench = _wrench_option(wrench)
        self._wrench_applied = True

    @property
    def measured_wrench(self) -> np.ndarray:
        """What the wrist sensor felt at the last step (N, N m, sensor frame), before any vendor's quantisation; a copy."""
        return self._wrench.copy()

    def _apply_wrist_wrench(self) -> None:
        """The contact, turned from the sensor frame into the world frame MuJoCo applies it in.

        The hand's orientation is taken for the pose the coming step starts from (after a step,
        data.xmat still holds the pose before its integration). No contact (the usual case) is
        zero in any frame: the kinematics, a third of a step's cost, are then not needed, and
        the step itself recomputes them from the joints either way.
        """
        if not self._wrist_wrench.any():
            self.data.xfrc_applied[self._ft_body] = 0.0
            self._wrench_applied = False  # and it stays zero: only this applies a wrench there
            return
        mujoco.mj_kinematics(self.model, self.data)
        body = self._ft_body
        rotation = self.data.xmat[body].reshape(3, 3)
        applied = self.data.xfrc_applied[body]
        np.matmul(rotation, self._wrist_wrench[:3], out=applied[:3])
        np.matmul(rotation, self._wrist_wrench[3:], out=applied[3:])

    def _serve_boards(self) -> None:
        """One ADC conversion of all channels, and vendor A's answer to a new request (no allocation)."""
        regs = self._registers
        np.negative(self._ft_reading, out=self._wrench)  # MuJoCo's reading is the arm's pull on the tool
        volts, counts, volts_ft = self._volts, self._counts, self._volts_ft
        # vendor B's gauges on ADC 0-5, the DAC looped back on ADC 6-7
        np.matmul(self._ft_inverse, self._wrench, out=volts_ft)
        np.add(volts_ft, ft_models.OFFSET, out=volts_ft)
        np.multiply(self._dac_looped, VOLTS_PER_COUNT, out=self._volts_looped)
        if self._adc_noise > 0:
            self._rng.standard_normal(out=self._noise)
            self._noise *= self._adc_noise
            volts += self._noise
        np.multiply(volts, 1.0 / VOLTS_PER_COUNT, out=counts)
        np.rint(counts, out=counts)
        _CLIP(counts, _INT16_MIN, _INT16_MAX, out=counts)  # (whole numbers: a zero's sign is lost in the cast)
        words = regs.words
        seq = words[W_BOARD_SEQ]
        words[W_BOARD_SEQ] = seq + 1
        np.copyto(regs.adc, counts, casting="unsafe")
        words[W_BOARD_STEP] = self._steps
        words[W_BOARD_SEQ] = seq + 2
        # vendor A on parallel-port channels 0-7: latch on a new request, data first, then ACK
        request = int(regs.pio_out[ft_models.A_REQUEST])
        if request != self._a_ack:
            a = self._a_counts
            np.divide(self._wrench, ft_models.A_SCALE, out=a)
            np.rint(a, out=a)
            clipped = bool(np.any(np.abs(a) > 32767))
            np.clip(a, -32768, 32767, out=a)
            data = regs.pio_in[ft_models.A_DATA : ft_models.A_DATA + 6].view(np.int16)
            np.copyto(data, a, casting="unsafe")
            regs.pio_in[ft_models.A_STATUS] = ft_models.A_STATUS_POWERED | (ft_models.A_STATUS_CLIPPED if clipped else 0)
            regs.pio_in[ft_models.A_ACK] = request
            self._a_ack = request

    def target_at(self, t: float, out: np.ndarray) -> np.ndarray:
        """The target's pose (position m, rotation vector rad) at sim time t, into out (no allocation)."""
        angle = self._target_rate * t + self._target_phase
        center, radius = self._target_center, self._target_radius
        out[0] = center[0] + radius * math.cos(angle)
        out[1] = center[1] + radius * math.sin(angle)
        out[2] = center[2]
        out[3:] = self._target_pose[3:]
        return out

    @property
    def target_pose(self) -> np.ndarray:
        """The target's pose at the current sim time, a copy (zeros without a target)."""
        return self._target_pose.copy()

    def _move_target(self) -> None:
        """Put the marker where the path says at data.time (kinematically: the mocap position)."""
        self.target_at(self.data.time, self._target_pose)
        np.copyto(self.data.mocap_pos[0], self._target_pose[:3])

    def _servo(self, data: mujoco.MjData) -> None:
        """Position mode: PD to the (joint-limited) q_cmd plus gravity, clipped, into qfrc_applied.

        Written as Kd (v_ref - qd) with v_ref = (Kp / Kd) e, which is Kp e - Kd qd, except that
        v_ref is capped by the braking curve sqrt(2 a |e|): no faster than the joint can stop
        from at a = half its torque limit over its inertia. See the module docstring.
        """
        q_cmd, tau, v_ref = self._q_cmd, self._servo_tau, self._scratch
        np.clip(q_cmd, self._q_min, self._q_max, out=q_cmd)
        qpos, qvel = data.qpos, data.qvel
        np.subtract(q_cmd, qpos, out=tau)  # tau holds the error e for now
        np.abs(tau, out=v_ref)
        np.multiply(v_ref, self._servo_brake2, out=v_ref)
        np.sqrt(v_ref, out=v_ref)  # |v_ref| bound: sqrt(2 a |e|)
        np.multiply(tau, self._servo_ratio, out=tau)  # (Kp / Kd) e
        np.clip(tau, -v_ref, v_ref, out=v_ref)
        np.subtract(v_ref, qvel, out=tau)
        np.multiply(tau, self.servo_kd, out=tau)
        np.add(tau, self.gravity_torque(qpos, self._gravity), out=tau)
        _CLIP(tau, self._torque_floor, self._torque_limits, data.qfrc_applied)

    def _command_stale(self, now: float) -> bool:
        """The drive's watchdog, brakes off and the command unchanged since `_command_seen_at` (`step`
        restarts it at each new command): stale past `command_timeout`."""
        stale = self._command_timeout > 0 and now - self._command_seen_at > self._command_timeout
        if stale and not self._watchdog_holding:
            self._watchdog_holding = True
            self.watchdog_trips += 1
        return stale

    def _read_command(self, source: np.ndarray, target: np.ndarray) -> None:
        """Copy one command register under the command seqlock; keep the last good command if the
        driver is mid-write."""
        words, scratch = self._registers.words, self._scratch
        before = words[W_CMD_SEQ]
        if not before & 1:  # the usual case: no write under way, one copy (an assignment: copyto's dispatch costs more)
            scratch[...] = source
            if words[W_CMD_SEQ] == before:
                target[...] = scratch
                return
        for _ in range(_COMMAND_READ_TRIES - 1):  # (the look above was the first)
            before = words[W_CMD_SEQ]
            if before & 1:
                continue
            scratch[...] = source
            if words[W_CMD_SEQ] == before:
                target[...] = scratch
                return

    def _publish(self) -> None:
        regs = self._registers
        words = regs.words
        seq = words[W_STATE_SEQ]
        words[W_STATE_SEQ] = seq + 1  # odd: readers retry
        regs.q[...] = self._qpos  # (assignments: copyto's dispatch costs more than six joints' copy)
        regs.qd[...] = self._qvel
        self._time = now = self.data.time  # data.time as a float, read once a step (MjData's attributes are slow)
        regs.reals[W_SIM_TIME] = now
        words[W_STEP_COUNT] = self._steps
        if self.has_target:  # (without one, its pose stays the zeros the segment was made with)
            copyto(regs.target, self._target_pose)
        words[W_STATE_SEQ] = seq + 2

    def close(self) -> None:
        """Unmap and unlink the register segment; safe to call twice."""
        registers = self.__dict__.pop("_registers", None)
        if registers is not None:
            registers.release()
        if self.__dict__.pop("_shm", None) is not None:
            unlink_quietly("shm", self.name)

    def __enter__(self) -> MujocoArmPlant:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def route_mujoco_log(log_dir: str) -> None:
    """MuJoCo's warnings (an unstable simulation, a contact buffer full) go to this process's stderr,
    as one line each, and to `log_dir`/MUJOCO_LOG.TXT when the run has an output directory (`pbo run
    --out`); MuJoCo's own handler would write MUJOCO_LOG.TXT into the operator's working directory."""
    _import_mujoco()
    log = Path(log_dir) / "MUJOCO_LOG.TXT" if log_dir else None

    def warn(message: str) -> None:
        line = f"{time.strftime('%Y-%m-%d %H:%M:%S')} WARNING: {message}"
        print(f"plant: MuJoCo warning: {message}", file=sys.stderr, flush=True)
        if log is not None:
            try:
                with log.open("a") as file:
                    file.write(line + "\n")
            except OSError as exc:
                print(f"plant: cannot write {log}: {exc}", file=sys.stderr, flush=True)

    mujoco.set_mju_user_warning(warn)


def _import_mujoco() -> None:
    """MuJoCo, imported by the first plant made (each plant routes its log first), not with this module:
    `pbo check` reads the plant's `Options` and loads no simulator."""
    global mujoco
    import mujoco


def _vector(value: Any, where: str) -> np.ndarray:
    try:
        vector = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        vector = np.zeros(0)
    if vector.shape != (3,) or not np.all(np.isfinite(vector)):
        raise ValueError(f"plant option {where} must be 3 finite numbers, got: {value!r}")
    return vector


def _positive(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise ValueError(f"plant option {where} must be a finite number > 0, got: {value!r}")
    return float(value)


def _wrench_option(value: Any) -> np.ndarray:
    try:
        wrench = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        wrench = np.zeros(0)
    if wrench.shape != (6,) or not np.all(np.isfinite(wrench)):
        raise ValueError(f"plant option wrist_wrench must be 6 finite numbers [fx, fy, fz, tx, ty, tz] (N, N m), got: {value!r}")
    return wrench


def _target_options(target: Any) -> dict[str, Any] | None:
    """The checked `target:` plant option, or None without one."""
    if target is None:
        return None
    if not isinstance(target, Mapping):
        raise ValueError(f"plant option target must be a mapping {{center, radius, period, phase, orientation}}, got: {target!r}")
    unknown = sorted(set(target) - set(_TARGET_OPTIONS))
    if unknown:
        raise ValueError(f"unknown plant target option(s) {unknown}; valid options: {', '.join(_TARGET_OPTIONS)}")
    missing = [key for key in ("center", "radius", "period") if key not in target]
    if missing:
        raise ValueError(f"plant option target needs {', '.join(missing)} (a circle: center [x, y, z] m, radius m, period s)")
    phase = target.get("phase", 0.0)
    if isinstance(phase, bool) or not isinstance(phase, (int, float)) or not math.isfinite(phase):
        raise ValueError(f"plant option target.phase must be a finite number (rad), got: {phase!r}")
    return {
        "center": _vector(target["center"], "target.center"),
        "radius": _positive(target["radius"], "target.radius"),
        "period": _positive(target["period"], "target.period"),
        "phase": float(phase),
        "orientation": _vector(target.get("orientation", [0.0, 0.0, 0.0]), "target.orientation"),
    }
