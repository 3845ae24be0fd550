"""The vision subsystem's device driver (TR Figures 12 and 13): where the target is, as a camera sees it.

It attaches, like the arm's driver, to the register segment the plant created (never creating
or removing it) and reads the target's world pose (position m, then rotation vector rad) that
the plant publishes with the arm's state under the state seqlock. It models the two flaws of a
real vision system that matter to a visual servo:

- `noise` (m, default 0): zero-mean Gaussian noise of that standard deviation added to each
  position coordinate of every frame; seeded (`seed`, default 0), so a run is repeatable.
- `latency` (frames, default 0): the pose reported is the one captured `latency` frames before.
  A frame is one `read_target` call (the camera is sampled by the task that reads it), so at a
  task period T the delay is latency * T. Until that many frames exist, the first is reported.

The per-cycle call `read_target` allocates nothing: frames go into a preallocated ring.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from drivers.mujoco_arm.registers import W_SIM_TIME, W_STATE_SEQ, W_TARGET, DeviceError, attach_registers
from pbo_runtime import DeviceDriver

_OPTIONS = ("latency", "noise", "seed")
_SPINS_BEFORE_YIELD = 100
_STUCK_AFTER_S = 0.5


def _check_options(options: Mapping[str, Any]) -> tuple[float, int, int]:
    unknown = sorted(set(options) - set(_OPTIONS))
    if unknown:
        raise ValueError(f"unknown camera driver option(s) {unknown}; valid options: {', '.join(_OPTIONS)}")
    noise = options.get("noise", 0.0)
    if isinstance(noise, bool) or not isinstance(noise, (int, float)) or not (math.isfinite(noise) and 0 <= noise <= 10):
        raise ValueError(f"camera option noise must be a number in [0, 10] (standard deviation, m), got: {noise!r}")
    latency = options.get("latency", 0)
    if isinstance(latency, bool) or not isinstance(latency, int) or not 0 <= latency <= 10_000:
        raise ValueError(f"camera option latency must be a whole number of frames in [0, 10000], got: {latency!r}")
    seed = options.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= 2**32 - 1:
        raise ValueError(f"camera option seed must be an integer in [0, 4294967295], got: {seed!r}")
    return float(noise), latency, seed


class VisionCamera(DeviceDriver):
    """The target's pose as a camera reports it. options: `noise` (m), `latency` (frames), `seed`."""

    KIND = "camera"
    OPTIONS = _OPTIONS
    NEEDS_PLANT = True
    PLANT_OPTIONS = ("target",)

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> None:
        """ValueError for an unknown or bad option (the checker reports it as E607)."""
        _check_options(options)

    def __init__(self, registers: str, options: Mapping[str, Any]) -> None:
        super().__init__(registers, options)
        self.noise, self.latency, self.seed = _check_options(self.options)
        self._regs = attach_registers(registers)
        if not self._regs.words[W_TARGET]:
            self._regs.release()
            raise DeviceError(
                f"camera on registers {registers!r}: the plant has no target to see; give the plant the option "
                "target: {center: [x, y, z], radius: r, period: T}"
            )
        self._words = self._regs.words
        self._reals = self._regs.reals
        self._target = self._regs.target
        self._rng = np.random.Generator(np.random.PCG64(self.seed))
        slots = self.latency + 1
        self._poses = np.zeros((slots, 6))  # ring of captured frames
        self._times = np.zeros(slots)
        self._noise = np.zeros(3)
        self._frames = 0  # frames captured so far
        self._stuck_deadline = 0.0

    def read_target(self, x_out: np.ndarray) -> float:
        """Fill x_out (6,) with the target pose `latency` frames ago, noise added; return its sim time, s."""
        slots = self.latency + 1
        slot = self._frames % slots
        pose = self._poses[slot]
        self._times[slot] = self._capture(pose)
        if self.noise > 0:
            self._rng.standard_normal(out=self._noise)
            self._noise *= self.noise
            pose[:3] += self._noise
        self._frames += 1
        # the oldest frame in the ring (or the first, until the ring is full)
        shown = self._frames % slots if self._frames > self.latency else 0
        np.copyto(x_out, self._poses[shown])
        return float(self._times[shown])

    def _capture(self, pose: np.ndarray) -> float:
        words = self._words
        tries = 0
        while True:
            before = words[W_STATE_SEQ]
            if not before & 1:
                np.copyto(pose, self._target)
                sim_time: float = self._reals[W_SIM_TIME]
                if words[W_STATE_SEQ] == before:
                    return sim_time
            tries += 1
            if tries == _SPINS_BEFORE_YIELD:
                self._stuck_deadline = time.monotonic() + _STUCK_AFTER_S
            elif tries > _SPINS_BEFORE_YIELD:
                if time.monotonic() > self._stuck_deadline:
                    raise DeviceError(
                        f"camera on registers {self.registers!r}: the plant has been mid-publish for over "
                        f"{_STUCK_AFTER_S} s (state seqlock stuck odd); did the plant process die?"
                    )
                os.sched_yield()

    @property
    def frames(self) -> int:
        """Frames captured since the driver was opened."""
        return self._frames

    def close(self) -> None:
        """Unmap the registers (idempotent); the plant owns and removes the segment."""
        regs = self.__dict__.pop("_regs", None)
        if regs is None:
            return
        for name in ("_words", "_reals", "_target"):
            self.__dict__.pop(name, None)
        regs.release()
