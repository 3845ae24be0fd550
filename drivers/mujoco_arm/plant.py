"""The simulated arm itself: a MuJoCo model of a named robot, stepped by a plant host process.

The plant owns the register segment (see `registers`): it publishes the measured state after every
step and applies whatever the driver last commanded. It starts with the brakes engaged, like the
real PUMA, so the arm does not fall before a controller is on. It does no real-time pacing: the
host calls `step()` once per `timestep` of wall time (or as fast as it likes, in tests).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

import mujoco
import numpy as np

from drivers.mujoco_arm.registers import (
    MAGIC,
    MODE_TORQUE,
    W_BRAKE,
    W_CMD_SEQ,
    W_MAGIC,
    W_MODE,
    W_PLANT_PID,
    W_SIM_TIME,
    W_STATE_SEQ,
    W_STEP_COUNT,
    W_TIMESTEP,
    create_registers,
)
from drivers.robots import robot, to_mjcf
from pbo_runtime._shm import unlink_quietly

_OPTIONS = ("q0",)
# A driver's command write takes about a microsecond; if the seqlock is still odd after this many
# looks the driver was preempted (or died) mid-write, and the plant keeps the previous command
# rather than wait on it.
_COMMAND_READ_TRIES = 64


class MujocoArmPlant:
    """One MuJoCo arm behind a register segment named `registers_name`.

    options: `q0` (sequence of ndof floats, rad): the braked start pose; default the robot's home.
    """

    def __init__(self, registers_name: str, model: str, timestep: float, options: Mapping[str, Any]) -> None:
        unknown = sorted(set(options) - set(_OPTIONS))
        if unknown:
            raise ValueError(f"unknown mujoco_arm plant option(s) {unknown}; valid options: {', '.join(_OPTIONS)}")
        if not timestep > 0:
            raise ValueError(f"plant timestep must be > 0, got: {timestep}")
        description = robot(model)
        n = description.ndof
        q0 = np.array(options.get("q0", description.q0), dtype=np.float64)
        if q0.shape != (n,):
            raise ValueError(f"plant option q0 must have {n} values for {model!r}, got shape: {q0.shape}")

        self.name = registers_name
        self.timestep = float(timestep)
        self.ndof = n
        self.description = description
        self.model = mujoco.MjModel.from_xml_string(to_mjcf(description, self.timestep))
        self.data = mujoco.MjData(self.model)
        self.data.qpos[:] = q0
        mujoco.mj_forward(self.model, self.data)

        self._torque_limits = description.torque_limits.copy()
        self._tau = np.zeros(n)  # last consistent command, preallocated for step()
        self._scratch = np.zeros(n)
        self._brake_pose = q0.copy()
        self._braked = True
        self._steps = 0

        self._shm, self._registers = create_registers(registers_name, n)
        try:
            regs = self._registers
            regs.dh[:] = description.dh
            regs.dyn[:] = description.dyn
            regs.limits[:, :2] = description.joint_limits
            regs.limits[:, 2] = description.torque_limits
            regs.reals[W_TIMESTEP] = self.timestep
            regs.words[W_PLANT_PID] = os.getpid()
            self._publish()
            regs.words[W_MAGIC] = MAGIC  # last: a driver refuses the segment until it is complete
        except BaseException:
            self.close()
            raise

    @property
    def sim_time(self) -> float:
        """Simulated time since creation, s."""
        return float(self.data.time)

    @property
    def brakes_engaged(self) -> bool:
        return self._braked

    def step(self) -> None:
        """Advance the simulation by exactly one timestep and publish the new state."""
        regs = self._registers
        data = self.data
        braked = regs.words[W_BRAKE] != 0
        if braked and not self._braked:
            self._brake_pose[:] = data.qpos  # brakes grip where the arm is now
        self._braked = braked
        if braked:
            data.qpos[:] = self._brake_pose
            data.qvel[:] = 0.0
            data.qfrc_applied[:] = 0.0
        else:
            if regs.words[W_MODE] == MODE_TORQUE:
                self._read_command()
                np.clip(self._tau, -self._torque_limits, self._torque_limits, out=data.qfrc_applied)
            else:
                data.qfrc_applied[:] = 0.0
        mujoco.mj_step(self.model, data)
        if braked:
            data.qpos[:] = self._brake_pose
            data.qvel[:] = 0.0
        self._steps += 1
        self._publish()

    def _read_command(self) -> None:
        """Copy tau under the command seqlock; keep the last good command if the driver is mid-write."""
        regs = self._registers
        words = regs.words
        for _ in range(_COMMAND_READ_TRIES):
            before = words[W_CMD_SEQ]
            if before & 1:
                continue
            np.copyto(self._scratch, regs.tau)
            if words[W_CMD_SEQ] == before:
                np.copyto(self._tau, self._scratch)
                return

    def _publish(self) -> None:
        regs = self._registers
        words = regs.words
        seq = words[W_STATE_SEQ]
        words[W_STATE_SEQ] = seq + 1  # odd: readers retry
        np.copyto(regs.q, self.data.qpos)
        np.copyto(regs.qd, self.data.qvel)
        regs.reals[W_SIM_TIME] = self.data.time
        words[W_STEP_COUNT] = self._steps
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
