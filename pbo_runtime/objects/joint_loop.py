"""A joint's position loop as a sampled system: the gains a bandwidth asks for, and whether they are stable.

Each joint is a double integrator 1/(I s² + b s), I its reflected inertia (the mass matrix's
diagonal element, armature included) and b its viscous friction (the robot file's damping), driven
by a PD(+I) controller through a zero-order hold of period T, with `delay` periods between the
sample the controller reads and the torque reaching the arm (one between two tasks: the robot
interface publishes q_m, the controller answers, the interface applies it the next cycle). The
closed loop's eigenvalues say whether it is stable (all inside the unit circle) and how well damped
(the damping ratio of each pole, mapped back by s = ln z / T). A joint's inertia changes with the
pose: a loop is checked at inertias spanning the arm's range, since the lightest pose is where a
gain is most likely to be too high. Under computed torque (the controller's output an acceleration
that inverse dynamics multiplies by the arm's mass matrix) the model cancels the inertia: the gains
act on a unit inertia, and only the uncancelled friction b / I changes with the pose.

No simulator is needed: this is numpy only, for `pbo check`, `pbo set`, `pbo robot` and the
controllers' init.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from pbo_runtime.objects.waits import sleep_while_cycling

#: The damping ratio under which a stable loop is worth a warning: it rings.
LOW_DAMPING = 0.3
#: The damping ratio `design_gains` keeps at every pose, when the damping asked is at least that.
DESIGN_DAMPING = 0.4
#: Inertias at which a loop is checked between a joint's lightest and heaviest pose.
_INERTIA_POINTS = 9
#: Design inertias `design_gains` tries, heaviest first.
_DESIGN_POINTS = 40


@dataclass(frozen=True)
class LoopGains:
    """One joint's gains: N m/rad, N m s/rad, N m/(rad s)."""

    kp: float
    kd: float
    ki: float = 0.0


def bandwidth_gains(inertia: float, bandwidth: float, damping: float = 1.0, integral_time: float = 0.0,
                    viscous: float = 0.0) -> LoopGains:
    """kp = I w², kd = 2 ζ I w - b: a loop of natural frequency w and damping ratio ζ at inertia I,
    counting the joint's own viscous friction b; ki = kp / integral_time (0: no integral action).
    A joint whose friction alone damps it more than that gets no kd, and the kp that puts its
    slow pole at w: kp = w (b - I w)."""
    wanted = 2.0 * damping * inertia * bandwidth
    if viscous <= wanted:
        kp, kd = inertia * bandwidth * bandwidth, wanted - viscous
    else:
        kp, kd = max(inertia * bandwidth * bandwidth, bandwidth * (viscous - inertia * bandwidth)), 0.0
    return LoopGains(kp, kd, kp / integral_time if integral_time > 0 else 0.0)


@functools.lru_cache(maxsize=256)
def design_gains(low: float, high: float, bandwidth: float, damping: float, integral_time: float, period: float,
                 delay: int = 1, viscous: float = 0.0) -> tuple[LoopGains, float]:
    """The gains of `bandwidth_gains` for a joint whose inertia spans `low`..`high`, and the inertia
    they are made for: the heaviest, unless gains that stiff would leave the loop at a lighter pose
    poorly damped (its fast pole, kd / I, too close to the sampling rate): then the heaviest inertia
    for which every pose keeps a damping ratio of `DESIGN_DAMPING` (or the best there is).

    Kept per process: a controller replaced live by one with the same gains finds them made."""
    wanted = min(DESIGN_DAMPING, damping)
    best, best_damping = high, -math.inf
    for design in np.geomspace(high, low, _DESIGN_POINTS) if high > low else (high,):
        gains = bandwidth_gains(float(design), bandwidth, damping, integral_time, viscous)
        worst, stable_everywhere = _worst_damping(low, high, gains, period, delay, viscous)
        if not stable_everywhere:
            worst = -1.0
        if worst >= wanted * (1 - 1e-9):
            return gains, float(design)
        if worst > best_damping:
            best, best_damping = float(design), worst
    return bandwidth_gains(best, bandwidth, damping, integral_time, viscous), best


def closed_loop(inertia: float, gains: LoopGains, period: float, delay: int = 1, viscous: float = 0.0,
                computed_torque: bool = False) -> np.ndarray:
    """The closed loop's state matrix: state (q, qd, [integral], the commands on their way). The
    joint I qdd + b qd = torque, held over each period (exact zero-order hold). `computed_torque`:
    the controller's output is an acceleration that inverse dynamics turns into torque through the
    arm's model (times I), so its gains act on a unit inertia, the friction b / I left uncancelled."""
    if computed_torque:
        gains = LoopGains(gains.kp * inertia, gains.kd * inertia, gains.ki * inertia)
    t = period
    rate = viscous / inertia
    if rate * t > 1e-9:
        fade = math.exp(-rate * t)
        moved, kept = (1.0 - fade) / rate, fade  # q gains moved * qd; qd keeps kept * qd
        push_q, push_qd = (t - moved) / viscous, (1.0 - fade) / viscous
    else:
        moved, kept = t, 1.0
        push_q, push_qd = t * t / (2.0 * inertia), t / inertia
    integral = gains.ki > 0
    n = 2 + int(integral) + delay
    a = np.zeros((n, n))
    command = np.zeros(n)  # the torque the controller computes now, as a row over the state
    command[0], command[1] = -gains.kp, -gains.kd
    if integral:
        command[2] = 1.0
    first = 2 + int(integral)  # the newest command on its way
    applied = command if delay == 0 else np.eye(n)[n - 1]  # the torque on the arm this period
    a[0, 0], a[0, 1] = 1.0, moved
    a[1, 1] = kept
    a[0] += applied * push_q
    a[1] += applied * push_qd
    if integral:
        a[2, 2] = 1.0
        a[2, 0] = -gains.ki * t
    if delay:
        a[first] = command
        for k in range(first + 1, n):
            a[k, k - 1] = 1.0
    return a


def spectral_radius(inertia: float, gains: LoopGains, period: float, delay: int = 1, viscous: float = 0.0,
                    computed_torque: bool = False) -> float:
    """The largest eigenvalue's magnitude: < 1 stable."""
    return float(np.max(np.abs(np.linalg.eigvals(closed_loop(inertia, gains, period, delay, viscous, computed_torque)))))


def damping_ratio(inertia: float, gains: LoopGains, period: float, delay: int = 1, viscous: float = 0.0,
                  computed_torque: bool = False) -> float:
    """The smallest damping ratio of the loop's poles (1 for real poles, < 0 unstable)."""
    return _least_damping(np.linalg.eigvals(closed_loop(inertia, gains, period, delay, viscous, computed_torque)), period)


def _worst_damping(low: float, high: float, gains: LoopGains, period: float, delay: int, viscous: float) -> tuple[float, bool]:
    """(the least damping ratio over the inertias from `low` to `high`, whether the loop is stable at
    every one): `damping_ratio` and `stable` from one eigenvalue problem an inertia. In a live
    spawn's init the RTPU's due cycles run between two inertias, so no step lasts near a period."""
    worst, stable_everywhere = math.inf, True
    for inertia in inertias(low, high):
        sleep_while_cycling(0)
        poles = np.linalg.eigvals(closed_loop(float(inertia), gains, period, delay, viscous))
        worst = min(worst, _least_damping(poles, period))
        stable_everywhere = stable_everywhere and float(np.max(np.abs(poles))) < 1.0 - 1e-9
    return worst, stable_everywhere


def _least_damping(poles: np.ndarray, period: float) -> float:
    ratios = []
    for z in poles:
        if abs(z) < 1e-12:
            continue  # a pure delay: no dynamics
        s = np.log(complex(z)) / period
        ratios.append(-s.real / abs(s) if abs(s) > 0 else 1.0)
    return float(min(ratios)) if ratios else 1.0


def inertias(low: float, high: float) -> np.ndarray:
    """The inertias a loop is checked at: both ends and a geometric spread between."""
    if high <= low * (1 + 1e-12):
        return np.array([low])
    return np.geomspace(low, high, _INERTIA_POINTS)


def stable(low: float, high: float, gains: LoopGains, period: float, delay: int = 1, viscous: float = 0.0,
           computed_torque: bool = False) -> bool:
    """Whether the loop is stable at every inertia from `low` to `high`."""
    return all(spectral_radius(i, gains, period, delay, viscous, computed_torque) < 1.0 - 1e-9 for i in inertias(low, high))


@dataclass(frozen=True)
class LoopVerdict:
    """What the analysis says of one joint's loop over its inertia range."""

    stable: bool
    worst_inertia: float  # where the loop is least stable (largest spectral radius), kg m²
    spectral_radius: float  # there
    damping: float  # the smallest damping ratio over the range (meaningful when stable)
    kd_range: tuple[float, float] | None  # when unstable: the kd that make it stable at this kp and ki, None: none does
    scale: float  # when unstable: the largest factor on all three gains that keeps it stable (1 when stable)

    def bound_text(self, gains: LoopGains) -> str:
        """The gain bound that makes the loop stable, in words."""
        if self.kd_range is not None:
            low, high = self.kd_range
            if low > 0 and gains.kd <= low:
                return f"stable for kd > {low:.4g} (at kp {gains.kp:.4g})"
            return f"stable for kd < {high:.4g} (at kp {gains.kp:.4g})" + (f" and kd > {low:.4g}" if low > 0 else "")
        return (f"no kd makes it stable at kp {gains.kp:.4g}; it is stable for kp < {gains.kp * self.scale:.4g} "
                f"with kd < {gains.kd * self.scale:.4g}" + (f" and ki < {gains.ki * self.scale:.4g}" if gains.ki else ""))


def analyse(low: float, high: float, gains: LoopGains, period: float, delay: int = 1, viscous: float = 0.0,
            computed_torque: bool = False) -> LoopVerdict:
    """The verdict on one joint's loop, inertia from `low` to `high` kg m², viscous friction `viscous`
    (`computed_torque`: the gains are accelerations, `closed_loop`)."""
    ct = computed_torque
    points = inertias(low, high)
    radii = [spectral_radius(i, gains, period, delay, viscous, ct) for i in points]
    worst = int(np.argmax(radii))
    is_stable = radii[worst] < 1.0 - 1e-9
    damping = min(damping_ratio(i, gains, period, delay, viscous, ct) for i in points) if is_stable else -1.0
    if is_stable:
        return LoopVerdict(True, float(points[worst]), float(radii[worst]), damping, None, 1.0)
    kd_range = _stable_kd(low, high, gains, period, delay, viscous, ct)
    scale = _stable_scale(low, high, gains, period, delay, viscous, ct)
    return LoopVerdict(is_stable, float(points[worst]), float(radii[worst]), damping, kd_range, scale)


def _stable_kd(low: float, high: float, gains: LoopGains, period: float, delay: int,
               viscous: float, computed_torque: bool) -> tuple[float, float] | None:
    """The interval of kd that keeps the loop stable at this kp and ki over the range, found on a
    logarithmic scan and refined by bisection at its ends; None when no kd on the scan is stable."""
    top = 4.0 * (1.0 if computed_torque else high) / period  # no loop with a period of delay is stable past kd T / I of a few
    candidates = np.geomspace(top * 1e-9, top, 160)
    ok = [stable(low, high, LoopGains(gains.kp, float(kd), gains.ki), period, delay, viscous, computed_torque)
          for kd in candidates]
    if not any(ok):
        return None
    first = ok.index(True)
    last = len(ok) - 1 - ok[::-1].index(True)

    def is_ok(kd: float) -> bool:
        return stable(low, high, LoopGains(gains.kp, kd, gains.ki), period, delay, viscous, computed_torque)

    lower = 0.0 if first == 0 and is_ok(0.0) else _edge(is_ok, float(candidates[first - 1]) if first else 0.0,
                                                         float(candidates[first]))
    upper = _edge(is_ok, float(candidates[last]), float(candidates[last + 1])) if last + 1 < len(ok) else math.inf
    return lower, upper


def _stable_scale(low: float, high: float, gains: LoopGains, period: float, delay: int, viscous: float,
                  computed_torque: bool) -> float:
    """The largest s with the gains times s stable over the range (bisection on a log scale)."""
    def is_ok(s: float) -> bool:
        return stable(low, high, LoopGains(gains.kp * s, gains.kd * s, gains.ki * s), period, delay, viscous, computed_torque)

    if not (gains.kp or gains.kd or gains.ki):
        return math.inf
    hi = 1.0
    while is_ok(hi) and hi < 1e9:
        hi *= 2.0
    lo = hi / 2.0
    while not is_ok(lo) and lo > 1e-12:
        hi, lo = lo, lo / 2.0
    return _edge(is_ok, lo, hi)


def _edge(is_ok: Callable[[float], bool], inside: float, outside: float) -> float:
    """Where `is_ok` changes between `inside` and `outside` (either may be the stable one), to 1e-4."""
    good, bad = (inside, outside) if is_ok(inside) else (outside, inside)
    for _ in range(40):
        middle = 0.5 * (good + bad)
        if is_ok(middle):
            good = middle
        else:
            bad = middle
        if abs(good - bad) <= 1e-4 * max(abs(good), 1e-12):
            break
    return good
