"""The arm's device driver: what a task opens to read joint state and command the joints.

It attaches to the register segment the plant created (never creating or removing it) and moves
values with preallocated numpy views, so the per-cycle calls allocate no arrays.

A driver is opened in one mode (option `mode`): `torque` (`write_torque`, the default) or
`position` (`write_position`, tracked by the plant's joint servo; see `plant`). The other mode's
write is refused. Opening a driver claims nothing: a driver takes the arm when it releases the
brakes, which writes its mode into the `MODE` register, and the plant then applies only that
mode's command registers. Two drivers of different modes are kept apart by refusal, not by
"last one wins": `release_brakes` raises `DeviceError` while the brakes are already released in
the other mode, so a torque driver can never move an arm a position driver is commanding (nor
the reverse). The arm changes hands only through engaged brakes: the owner (its task turned off)
engages them, then the other driver releases them. Drivers of the same mode share the
registers, as before. Both command registers share one seqlock, which assumes one writer at a
time: only the driver holding the arm should write commands (the others' are ignored anyway).
A command with NaN or Inf is refused (`DeviceError`) and never written: the writing task goes to
ERROR, and the robot interface's error component engages the brakes.
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np
from numpy import copyto, isfinite

from drivers.mujoco_arm.registers import (
    MODE_NAMES,
    MODE_POSITION,
    MODE_TORQUE,
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
from pbo_runtime import Arm, DeviceDriver

_OPTIONS = ("mode",)
# Spins before the reader starts yielding the CPU to a plant preempted mid-publish (it may share
# the CPU), and how long it waits before calling the plant stuck.
_SPINS_BEFORE_YIELD = 100
_STUCK_AFTER_S = 0.5
_FAULTS_KEPT = 10  # the faults a driver keeps for the summary (an operator may clear and turn on again)
# np.count_nonzero's C function without its Python wrapper, which costs more than counting six joints
_COUNT_NONZERO: Any = getattr(getattr(getattr(np, "_core", None), "multiarray", None), "count_nonzero", np.count_nonzero)


class MujocoArmDriver(DeviceDriver):
    """Joint-level access to the simulated arm. options: `mode`, 'torque' (default) or 'position'."""

    KIND = "arm"
    OPTIONS = _OPTIONS
    NEEDS_PLANT = True

    OPTION_DEFAULTS: ClassVar[Mapping[str, Any]] = {"mode": "torque"}

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> None:
        """ValueError for an unknown option or mode (the checker reports it as E607)."""
        unknown = sorted(set(options) - set(_OPTIONS))
        if unknown:
            raise ValueError(f"unknown mujoco_arm driver option(s) {unknown}; valid options: {', '.join(_OPTIONS)}")
        mode = options.get("mode", cls.OPTION_DEFAULTS["mode"])
        if mode not in MODES:
            raise ValueError(f"mujoco_arm driver mode must be one of: {', '.join(MODES)}; got: {mode!r}")

    def __init__(self, registers: str, options: Mapping[str, Any]) -> None:
        super().__init__(registers, options)
        self.check_options(self.options)
        mode = self.options.get("mode", self.OPTION_DEFAULTS["mode"])
        self.mode: str = mode
        self._mode_word = MODES[mode]
        self._position = self._mode_word == MODE_POSITION
        self._positioned = False  # a position written by this driver since it was opened
        self._regs = attach_registers(registers)
        self.ndof: int = self._regs.layout.ndof
        self.timestep: float = self._regs.reals[W_TIMESTEP]
        # Bound once here so the per-cycle paths do no attribute look-ups through self._regs.
        self._words = self._regs.words
        self._reals = self._regs.reals
        self._q = self._regs.q
        self._qd = self._regs.qd
        self._tau = self._regs.tau
        self._q_cmd = self._regs.q_cmd
        self._stuck_deadline = 0.0
        self._finite = np.zeros(self.ndof, dtype=bool)  # per element of a command: finite (filled per write, no allocation)
        self._faults: list[dict[str, Any]] = []  # the divergences its task braked the arm for (brake_for_fault)

    # constants -------------------------------------------------------------------------------

    def arm(self) -> np.ndarray:
        """The arm's joint table (the ARM constant, columns `pbo_runtime.ARM_COLUMNS`), a copy: (ndof, Arm.WIDTH)."""
        return self._regs.arm.copy()

    def end_effector(self) -> np.ndarray:
        """Where the end effector is (the EE constant, `pbo_runtime.EE_COLUMNS`), a copy: (Arm.EE_WIDTH,)."""
        return self._regs.ee.copy()

    def joint_limits(self) -> np.ndarray:
        """(ndof, 2) lower, upper joint positions, rad (-inf and inf for a joint without a range)."""
        arm = self._regs.arm
        return np.where(arm[:, [Arm.LIMITED]] > 0, arm[:, [Arm.Q_MIN, Arm.Q_MAX]], [-np.inf, np.inf])

    def torque_limits(self) -> np.ndarray:
        """(ndof,) |tau| the plant applies at most, N m; larger commands are clipped."""
        return self._regs.arm[:, Arm.EFFORT].copy()

    # per cycle: no allocation ------------------------------------------------------------------

    def read_state(self, q_out: np.ndarray, qd_out: np.ndarray) -> float:
        """Fill q_out (rad) and qd_out (rad/s) from one consistent plant step; return its sim time, s."""
        words = self._words
        tries = 0
        while True:
            before = words[W_STATE_SEQ]
            if not before & 1:
                copyto(q_out, self._q)
                copyto(qd_out, self._qd)
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
        """Command joint torques, N m (the plant clips them to its torque limits). Torque mode only."""
        if self._position:
            raise DeviceError(self._wrong_mode("write_torque", "torque"))
        if _COUNT_NONZERO(isfinite(tau, self._finite)) != self.ndof:  # a non-finite command never reaches the arm
            raise DeviceError(self._not_finite("write_torque", "torque", tau))
        words = self._words
        seq = words[W_CMD_SEQ]
        words[W_CMD_SEQ] = seq + 1  # odd: the plant keeps the previous command
        copyto(self._tau, tau)
        words[W_CMD_SEQ] = seq + 2

    def write_position(self, q_cmd: np.ndarray) -> None:
        """Command joint positions, rad (the plant clips them to the joint limits). Position mode only."""
        if not self._position:
            raise DeviceError(self._wrong_mode("write_position", "position"))
        if _COUNT_NONZERO(isfinite(q_cmd, self._finite)) != self.ndof:
            raise DeviceError(self._not_finite("write_position", "position", q_cmd))
        words = self._words
        seq = words[W_CMD_SEQ]
        words[W_CMD_SEQ] = seq + 1  # odd: the plant keeps the previous command
        copyto(self._q_cmd, q_cmd)
        words[W_CMD_SEQ] = seq + 2
        self._positioned = True

    def _not_finite(self, call: str, what: str, command: np.ndarray) -> str:
        return (f"arm registers {self.registers!r}: {call} refused a {what} command that is not finite "
                f"([{', '.join(f'{x:g}' for x in np.ravel(command))}]); the arm keeps its previous "
                f"command: fix the task that computes it")

    def _wrong_mode(self, call: str, needs: str) -> str:
        return (
            f"arm registers {self.registers!r}: {call} needs a driver opened with mode: {needs}; this one has mode: {self.mode}"
        )

    # occasional ---------------------------------------------------------------------------------

    @property
    def step_count(self) -> int:
        """Plant steps taken (not seqlocked: for diagnostics)."""
        return int(self._words[W_STEP_COUNT])

    @property
    def commands_written(self) -> int:
        """Commands (torque or position) written into the registers, by any driver, since the plant started."""
        return int(self._words[W_CMD_SEQ]) // 2

    @property
    def active_mode(self) -> str:
        """The mode whose commands the plant applies when unbraked: 'none', 'torque' or 'position'."""
        word = int(self._words[W_MODE])
        return MODE_NAMES.get(word, f"unknown ({word})")

    @property
    def brakes_engaged(self) -> bool:
        """The brake request the plant obeys at its next step."""
        return bool(self._words[W_BRAKE])

    def release_brakes(self) -> None:
        """Take the arm in this driver's mode and let it move from the plant's next step.

        Command first: a holding torque, or (required in position mode) the position to hold,
        since the plant servoes to whatever q_cmd holds. Refused while the brakes are released in
        the other mode: another driver is commanding the arm.
        """
        words = self._words
        if self._position and not self._positioned:
            raise DeviceError(
                f"arm registers {self.registers!r}: write_position before release_brakes; "
                "the plant would servo the arm to whatever position the registers hold"
            )
        current = words[W_MODE]
        if words[W_BRAKE] == 0 and current != self._mode_word and current in (MODE_TORQUE, MODE_POSITION):
            raise DeviceError(
                f"arm registers {self.registers!r}: cannot release the brakes in {self.mode} mode, another "
                f"driver is commanding the arm in {MODE_NAMES[current]} mode; it must engage the brakes first"
            )
        words[W_MODE] = self._mode_word
        words[W_BRAKE] = 0

    def engage_brakes(self) -> None:
        """Hold the arm where it is from the plant's next step (commands are then ignored)."""
        self._words[W_BRAKE] = 1

    def brake_for_fault(self, message: str, command: str, at: float) -> None:
        """Engage the brakes for a fault of the arm the commanding task found (a divergence), and keep
        what it was: `figures()` hands it to the run's summary, which names the task that wrote
        `command` (the commanding task's in-var port that carried the command) and when (`at`, s on
        the run's clock)."""
        self.engage_brakes()
        if len(self._faults) < _FAULTS_KEPT:
            self._faults.append({"fault": message, "command": command, "at": at})

    def figures(self) -> dict[str, Any]:
        """For the run's summary: the faults the arm was braked for, the first with `fault`, `command`
        and `at` (what `brake_for_fault` was given) and every one in `faults`; {} without one."""
        if not self._faults:
            return {}
        return {**self._faults[0], "faults": list(self._faults)}

    def close(self) -> None:
        """Unmap the registers (idempotent); the plant owns and removes the segment."""
        regs = self.__dict__.pop("_regs", None)
        if regs is None:
            return
        for name in ("_words", "_reals", "_q", "_qd", "_tau", "_q_cmd"):
            self.__dict__.pop(name, None)
        regs.release()
