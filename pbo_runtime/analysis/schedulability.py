"""Whether each task of a configuration meets its deadline on its RTPU: non-preemptive response-time analysis.

An RTPU's executive is one thread that never preempts a cycle (rtpu/_executive.py). Among the
released tasks it picks critical before not, then the earliest deadline (release + period),
then the higher `priority`; a cycle, once started, runs to its end. So a task waits for:

- blocking: one cycle that started just before its release and has lower urgency (a non-critical
  task's cycle, for a critical task; or a task of its own kind whose deadline is later);
- interference: every cycle of a more urgent kind released before it starts (the critical
  tasks, for a non-critical one), and every cycle of its own kind whose deadline is not later.

Within one kind the executive is non-preemptive EDF; the response time of each task is computed
with George, Rivierre and Spuri's analysis of non-preemptive EDF (INRIA RR-2966, 1996), the
critical tasks counted as a higher level for the non-critical ones, and the non-critical ones
counted as blocking only for the critical ones. Releases are sporadic: any pattern the periods
allow (a periodic task at most once per period, an aperiodic one at most once per
min_interarrival). The executive's aligned periodic releases are one such pattern, so a proven
deadline holds for them; a refuted one is missed by some pattern the model allows (docs/scheduling.md).
Times are counted in whole ticks (1 ns) so that "started one tick before" is exact.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

from pbo_runtime.config.model import Subsystem, TaskSpec

TICK = 1e-9  # seconds per tick of the analysis
POINTS_LIMIT = 200_000  # release offsets tried per task before the analysis gives up (R unbounded)
BUSY_LIMIT_PERIODS = 10_000  # a busy period longer than this many of the longest period counts as unbounded

PROVEN, REFUTED, MEETS, MAY_MISS, UNKNOWN = "proven", "refuted", "meets", "may miss", "unknown"


@dataclass(frozen=True)
class Load:
    """One task as the analysis sees it: execution time C, period T (= relative deadline D), its kind."""

    name: str
    cost: float  # seconds: C, the longest cycle counted
    period: float  # seconds: T, and the deadline D (the executive's deadline is release + period)
    critical: bool = False


@dataclass(frozen=True)
class Response:
    """A task's worst-case response time and what blocked it there."""

    time: float  # seconds from release to the end of its cycle (inf: unbounded, the RTPU is overloaded)
    blocked_by: str = ""  # the task whose cycle blocks it in the worst case ('' none)
    blocking: float = 0.0  # seconds of that blocking


@dataclass(frozen=True)
class Cost:
    """A task's execution time and where it came from: 'exec_max' or 'exec_p99' of a run, or 'wcet' of the file."""

    seconds: float
    source: str


@dataclass(frozen=True)
class Verdict:
    """One task of one RTPU in one configuration."""

    task: str
    rtpu: str
    critical: bool
    period: float  # T = D, seconds
    cost: Cost | None  # None: no execution time known (the task did not run in the profile, no wcet:)
    response: Response | None  # None: not analysed (a task of its RTPU has no cost)
    status: str  # PROVEN / REFUTED for a critical task, MEETS / MAY_MISS for another, UNKNOWN
    spec: TaskSpec

    @property
    def refuted(self) -> bool:
        return self.status == REFUTED


def response_times(loads: Sequence[Load], tick: float = TICK) -> dict[str, Response]:
    """The worst-case response time of every task sharing one non-preemptive MUF executive."""
    scaled = [_Scaled(load, tick) for load in loads]
    out = {}
    for task in scaled:
        higher = [j for j in scaled if j.critical and not task.critical]
        same = [j for j in scaled if j.critical == task.critical and j is not task]
        lower = [j for j in scaled if task.critical and not j.critical]
        ticks, who, blocking = _np_edf_response(task, higher, same, lower)
        out[task.name] = Response(ticks * tick if ticks != math.inf else math.inf, who, blocking * tick)
    return out


@dataclass
class _Scaled:
    """A load in whole ticks."""

    name: str
    c: int
    t: int
    critical: bool

    def __init__(self, load: Load, tick: float) -> None:
        self.name = load.name
        self.c = max(0, round(load.cost / tick))
        self.t = max(1, round(load.period / tick))
        self.critical = load.critical


def _np_edf_response(i: _Scaled, higher: list[_Scaled], same: list[_Scaled], lower: list[_Scaled]) -> tuple[float, str, int]:
    """(R_i in ticks or inf, the blocking task, its blocking): George et al. 1996, Theorem for NP-EDF,
    with `higher` tasks always more urgent and `lower` ones blocking only. D = T for every task.

    For the job of i released at `a` in a busy period that began at 0 with every other task
    released then: its start is the least t with
        t = B(a) + floor(a / T_i) C_i + sum_higher (1 + floor(t / T_j)) C_j
              + sum_{same j, D_j <= a + D_i} min(1 + floor(t / T_j), 1 + floor((a + D_i - D_j) / T_j)) C_j,
    B(a) the longest less urgent cycle less one tick; R_i = max over a of max(C_i, t + C_i - a).
    """
    level = [*higher, *same, i]
    longest = max(j.t for j in level)
    if sum(j.c / j.t for j in level) > 1.0:
        return math.inf, "", 0
    base_block, base_who = max(((j.c - 1, j.name) for j in lower if j.c > 0), default=(0, ""))
    limit = BUSY_LIMIT_PERIODS * longest
    busy = _fixed_point(lambda t: base_block + sum(-(-t // j.t) * j.c for j in level), max(1, sum(j.c for j in level)), limit)
    if busy is None:
        return math.inf, "", 0
    points = sorted({k * j.t + j.t - i.t for j in (*same, i) for k in range(busy // j.t + 2)
                     if 0 <= k * j.t + j.t - i.t < busy} | {0})
    if len(points) > POINTS_LIMIT:
        return math.inf, "", 0
    worst, worst_who, worst_block = -1, "", 0
    for a in points:
        deadline = a + i.t
        block, who = base_block, base_who
        for j in same:
            if j.t > deadline and j.c - 1 > block:
                block, who = j.c - 1, j.name
        fixed = block + (a // i.t) * i.c
        eligible = [(j, 1 + (deadline - j.t) // j.t) for j in same if j.t <= deadline]
        start = functools.partial(_job_start, fixed, higher, eligible)
        begins = _fixed_point(start, start(0), limit)
        if begins is None:
            return math.inf, "", 0
        response = max(i.c, begins + i.c - a)
        if response > worst:
            worst, worst_who, worst_block = response, who if block > 0 else "", block if block > 0 else 0
    return worst, worst_who, worst_block


def _job_start(fixed: int, higher: list[_Scaled], eligible: list[tuple[_Scaled, int]], t: int) -> int:
    """The right side of the start equation of `_np_edf_response` at `t` (`eligible`: same-level tasks with their job bound)."""
    return (fixed + sum((1 + t // j.t) * j.c for j in higher)
            + sum(min(1 + t // j.t, jobs) * j.c for j, jobs in eligible))


def _fixed_point(step: Callable[[int], int], start: int, limit: int) -> int | None:
    """The least fixed point of a non-decreasing step from `start`, or None past `limit` ticks."""
    t = start
    while True:
        following = step(t)
        if following == t:
            return t
        if following > limit:
            return None
        t = following


# --- a subsystem's configurations -----------------------------------------------------------


def analyse_configuration(subsystem: Subsystem, configuration: str, costs: Mapping[str, Cost],
                          placement: Mapping[str, str] | None = None) -> dict[str, list[Verdict]]:
    """Per RTPU (in the file's order), a verdict per task of `configuration` on it.

    `placement`: task -> RTPU where it differs from the file (a proposed move). An RTPU with a
    task of unknown cost is not analysed: every one of its tasks is UNKNOWN.
    """
    where = dict(placement or {})
    by_rtpu: dict[str, list[TaskSpec]] = {r.name: [] for r in subsystem.rtpus}
    for name in subsystem.configurations[configuration].tasks:
        spec = subsystem.tasks[name]
        by_rtpu.setdefault(where.get(name, spec.rtpu), []).append(spec)
    out: dict[str, list[Verdict]] = {}
    for rtpu, specs in by_rtpu.items():
        if not specs:
            continue
        known = all(s.name in costs for s in specs)
        times = response_times([Load(s.name, costs[s.name].seconds, s.period, s.critical) for s in specs]) if known else {}
        verdicts = []
        for s in specs:
            response = times.get(s.name)
            if response is None:
                status = UNKNOWN
            elif response.time <= s.period * (1 + 1e-12):
                status = PROVEN if s.critical else MEETS
            else:
                status = REFUTED if s.critical else MAY_MISS
            verdicts.append(Verdict(s.name, rtpu, s.critical, s.period, costs.get(s.name), response, status,
                                    replace(s, rtpu=rtpu)))
        out[rtpu] = verdicts
    return out


def analyse(subsystem: Subsystem, costs: Mapping[str, Cost],
            placement: Mapping[str, str] | None = None) -> dict[str, dict[str, list[Verdict]]]:
    """Every configuration of the file: configuration -> RTPU -> verdicts."""
    return {name: analyse_configuration(subsystem, name, costs, placement) for name in subsystem.configurations}


def critical_ok(verdicts: Mapping[str, Sequence[Verdict]]) -> bool:
    """No critical task of these RTPUs is refuted (unknown ones do not count against)."""
    return not any(v.refuted for vs in verdicts.values() for v in vs)


def measured_configurations(subsystem: Subsystem, costs: Mapping[str, Cost]) -> list[str]:
    """The configurations whose every task has a cost: the ones an allocation can be judged on."""
    return [name for name, c in subsystem.configurations.items() if all(t in costs for t in c.tasks)]
