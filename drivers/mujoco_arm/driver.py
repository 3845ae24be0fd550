"""The arm's device driver: what a task opens to read joint state and command joint torques.

It attaches to the register segment the plant created (never creating or removing it) and moves
values with preallocated numpy views, so the per-cycle calls allocate no arrays.
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from drivers.mujoco_arm.registers import (
    MODES,
    W_BRAKE,
    W_CMD_SEQ,
    W_MODE,
    W_SIM_TIME,
    W_STATE_SEQ,
    W_STEP_COUNT,
    W_TIMESTEP,
    DeviceError,
    attach_registers,
)
from pbo_runtime._driver import DeviceDriver

_OPTIONS = ("mode",)
# Spins before the reader starts yielding the CPU to a plant preempted mid-publish (it may share
# the CPU), and how long it waits before calling the plant stuck.
_SPINS_BEFORE_YIELD = 100
_STUCK_AFTER_S = 0.5


class MujocoArmDriver(DeviceDriver):
    """Joint-level access to the simulated arm. options: `mode` (only 'torque' for now)."""

    def __init__(self, registers: str, options: Mapping[str, Any]) -> None:
        super().__init__(registers, options)
        unknown = sorted(set(self.options) - set(_OPTIONS))
        if unknown:
            raise ValueError(f"unknown mujoco_arm driver option(s) {unknown}; valid options: {', '.join(_OPTIONS)}")
        mode = self.options.get("mode", "torque")
        if mode not in MODES:
            raise ValueError(f"mujoco_arm driver mode must be one of: {', '.join(MODES)}; got: {mode!r}")
        self.mode: str = mode
        self._regs = attach_registers(registers)
        self.ndof: int = self._regs.layout.ndof
        self.timestep: float = self._regs.reals[W_TIMESTEP]
        # Bound once here so the per-cycle paths do no attribute look-ups through self._regs.
        self._words = self._regs.words
        self._reals = self._regs.reals
        self._q = self._regs.q
        self._qd = self._regs.qd
        self._tau = self._regs.tau
        self._stuck_deadline = 0.0
        self._regs.words[W_MODE] = MODES[mode]

    # constants -------------------------------------------------------------------------------

    def dh(self) -> np.ndarray:
        """DH rows (theta_offset, d, a, alpha), a copy: shape (ndof, 4)."""
        return self._regs.dh.copy()

    def dynamics(self) -> np.ndarray:
        """DYN rows (mass, cx, cy, cz, Ixx, Iyy, Izz, Ixy, Ixz, Iyz, armature), a copy: (ndof, 11)."""
        return self._regs.dyn.copy()

    def joint_limits(self) -> np.ndarray:
        """(ndof, 2) lower, upper joint positions, rad."""
        return self._regs.limits[:, :2].copy()

    def torque_limits(self) -> np.ndarray:
        """(ndof,) |tau| the plant applies at most, N m; larger commands are clipped."""
        return self._regs.limits[:, 2].copy()

    # per cycle: no allocation ------------------------------------------------------------------

    def read_state(self, q_out: np.ndarray, qd_out: np.ndarray) -> float:
        """Fill q_out (rad) and qd_out (rad/s) from one consistent plant step; return its sim time, s."""
        words = self._words
        tries = 0
        while True:
            before = words[W_STATE_SEQ]
            if not before & 1:
                np.copyto(q_out, self._q)
                np.copyto(qd_out, self._qd)
                sim_time: float = self._reals[W_SIM_TIME]
                if words[W_STATE_SEQ] == before:
                    return sim_time
            tries += 1
            if tries >= _SPINS_BEFORE_YIELD:
                self._wait_for_publish(tries)

    def _wait_for_publish(self, tries: int) -> None:
        """Slow path of read_state: the plant is mid-publish for long; yield, and give up if stuck."""
        if tries == _SPINS_BEFORE_YIELD:
            self._stuck_deadline = time.monotonic() + _STUCK_AFTER_S
        elif time.monotonic() > self._stuck_deadline:
            raise DeviceError(
                f"arm registers {self.registers!r}: the plant has been mid-publish for over "
                f"{_STUCK_AFTER_S} s (state seqlock stuck odd); did the plant process die?"
            )
        os.sched_yield()

    def write_torque(self, tau: np.ndarray) -> None:
        """Command joint torques, N m (the plant clips them to its torque limits)."""
        words = self._words
        seq = words[W_CMD_SEQ]
        words[W_CMD_SEQ] = seq + 1  # odd: the plant keeps the previous command
        np.copyto(self._tau, tau)
        words[W_CMD_SEQ] = seq + 2

    # occasional ---------------------------------------------------------------------------------

    @property
    def step_count(self) -> int:
        """Plant steps taken (not seqlocked: for diagnostics)."""
        return int(self._words[W_STEP_COUNT])

    @property
    def commands_written(self) -> int:
        """Torque commands written into the registers, by any driver, since the plant started."""
        return int(self._words[W_CMD_SEQ]) // 2

    @property
    def brakes_engaged(self) -> bool:
        """The brake request the plant obeys at its next step."""
        return bool(self._words[W_BRAKE])

    def release_brakes(self) -> None:
        """Let the arm move from the plant's next step; command a holding torque first."""
        self._words[W_BRAKE] = 0

    def engage_brakes(self) -> None:
        """Hold the arm where it is from the plant's next step (commands are then ignored)."""
        self._words[W_BRAKE] = 1

    def close(self) -> None:
        """Unmap the registers (idempotent); the plant owns and removes the segment."""
        regs = self.__dict__.pop("_regs", None)
        if regs is None:
            return
        for name in ("_words", "_reals", "_q", "_qd", "_tau"):
            self.__dict__.pop(name, None)
        regs.release()
