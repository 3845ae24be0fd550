"""Propose an assignment of tasks to RTPUs under which every critical deadline is proven (TR §6).

The report's future work: "a global scheduling algorithm which can automatically map these tasks
to the RTPUs based on the timing and resource constraints of each task". Timing: the
non-preemptive response-time analysis of `analysis.schedulability`, in every configuration judged
(a task has one RTPU in all of them). Resources: a task that uses an exclusive device keeps its
RTPU (the device is taken as wired to the board that RTPU drives), and so does every task the
caller pins.

The search is exact within its budget: assignments with 0 moves, then 1, then 2, ..., depth first,
the task with the largest utilisation placed first (first-fit decreasing order), its own RTPU tried
first. Adding a task to an RTPU never shortens anyone's response time there, so a partial
assignment with a refuted deadline is cut at once. The first assignment found therefore moves
as few tasks as any assignment does.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from pbo_runtime.analysis.schedulability import Cost, Load, response_times
from pbo_runtime.config.model import Subsystem, TaskSpec

SEARCH_LIMIT = 200_000  # partial assignments tried before the search gives up


@dataclass(frozen=True)
class Proposal:
    """An assignment found: the tasks it moves (task -> (from RTPU, to RTPU)) and the full placement."""

    moves: Mapping[str, tuple[str, str]]
    placement: Mapping[str, str]  # every task judged -> its RTPU
    every_deadline: bool  # True: the non-critical tasks meet theirs too; False: only the critical ones are proven


@dataclass(frozen=True)
class Search:
    """What the search found (`proposal` None: no assignment exists, or `gave_up`)."""

    proposal: Proposal | None
    tried: int
    gave_up: bool


def pinned_tasks(subsystem: Subsystem, pins: Sequence[str] = (), free: Sequence[str] = ()) -> dict[str, str]:
    """Tasks that keep their RTPU, and why: each user of an exclusive device (unless in `free`), each of `pins`."""
    kept: dict[str, str] = {}
    for task in subsystem.tasks.values():
        exclusive = [d for d in task.resources if d in subsystem.devices and subsystem.devices[d].exclusive]
        if exclusive and task.name not in free:
            kept[task.name] = f"uses exclusive device '{exclusive[0]}'"
    for name in pins:
        kept[name] = "pinned (--pin)"
    return kept


def propose(subsystem: Subsystem, costs: Mapping[str, Cost], configurations: Sequence[str],
            kept: Mapping[str, str], max_moves: int | None = None, limit: int = SEARCH_LIMIT) -> Search:
    """The assignment with the fewest moves under which every critical deadline of `configurations` is proven.

    Preferred: one where the non-critical tasks meet their deadlines too; failing that, the
    critical ones alone. Every task of `configurations` needs a cost.
    """
    tasks = sorted({t for c in configurations for t in subsystem.configurations[c].tasks},
                   key=lambda t: (-costs[t].seconds / subsystem.tasks[t].period, subsystem.tasks[t].index))
    tried = 0
    verdicts: dict[tuple[frozenset[str], bool], bool] = {}  # an RTPU's task set -> it keeps its deadlines (shared by every pass)
    for every_deadline in (True, False):
        search = _Searcher(subsystem, costs, configurations, kept, every_deadline, limit - tried, verdicts)
        for moves in range(0, (len(tasks) if max_moves is None else max_moves) + 1):
            placement = search.place(tasks, moves)
            if placement is not None:
                specs = subsystem.tasks
                return Search(Proposal({t: (specs[t].rtpu, r) for t, r in placement.items() if r != specs[t].rtpu},
                                       placement, every_deadline), tried + search.tried, False)
            if search.gave_up:
                return Search(None, tried + search.tried, True)
        tried += search.tried
    return Search(None, tried, False)


class _Searcher:
    """Depth-first placement with a move budget, cut where a deadline is refuted."""

    def __init__(self, subsystem: Subsystem, costs: Mapping[str, Cost], configurations: Sequence[str],
                 kept: Mapping[str, str], every_deadline: bool, limit: int,
                 verdicts: dict[tuple[frozenset[str], bool], bool]) -> None:
        self.subsystem = subsystem
        self.costs = costs
        self.kept = kept
        self.every_deadline = every_deadline
        self.limit = limit
        self.tried = 0
        self.gave_up = False
        self.rtpus = [r.name for r in subsystem.rtpus]
        self.verdicts = verdicts
        self.members: dict[str, list[str]] = {}  # task -> the configurations judged that have it
        for configuration in configurations:
            for task in subsystem.configurations[configuration].tasks:
                self.members.setdefault(task, []).append(configuration)

    def place(self, tasks: list[str], moves: int) -> dict[str, str] | None:
        placement: dict[str, str] = {}
        found = self._place(tasks, 0, moves, placement)
        return dict(found) if found is not None else None

    def _place(self, tasks: list[str], at: int, moves: int, placement: dict[str, str]) -> dict[str, str] | None:
        if at == len(tasks):
            return placement
        name = tasks[at]
        spec = self.subsystem.tasks[name]
        choices = [spec.rtpu] if name in self.kept or moves == 0 else [spec.rtpu, *(r for r in self.rtpus if r != spec.rtpu)]
        for rtpu in choices:
            self.tried += 1
            if self.tried > self.limit:
                self.gave_up = True
                return None
            placement[name] = rtpu
            if self._fits(name, rtpu, placement):
                found = self._place(tasks, at + 1, moves - (rtpu != spec.rtpu), placement)
                if found is not None or self.gave_up:
                    return found
            del placement[name]
        return None

    def _fits(self, name: str, rtpu: str, placement: Mapping[str, str]) -> bool:
        """Every configuration with `name` in it: the tasks placed on `rtpu` so far keep their deadlines."""
        for configuration in self.members[name]:
            together = frozenset(t for t in self.subsystem.configurations[configuration].tasks if placement.get(t) == rtpu)
            key = (together, self.every_deadline)
            if key not in self.verdicts:  # the same set comes back at every move budget, and in other configurations
                self.verdicts[key] = meets([self.subsystem.tasks[t] for t in together], self.costs, self.every_deadline)
            if not self.verdicts[key]:
                return False
        return True


def meets(specs: Sequence[TaskSpec], costs: Mapping[str, Cost], every_deadline: bool = False) -> bool:
    """The tasks of one RTPU keep their deadlines: the critical ones (and every one, if `every_deadline`)."""
    times = response_times([Load(s.name, costs[s.name].seconds, s.period, s.critical) for s in specs])
    return all(times[s.name].time <= s.period * (1 + 1e-12) for s in specs if s.critical or every_deadline)


def period_needed(specs: Sequence[TaskSpec], costs: Mapping[str, Cost], task: str, rounds: int = 20) -> float | None:
    """The shortest period (found by iterating T = R(T)) at which `task` meets its deadline among `specs`, or None."""
    period = next(s.period for s in specs if s.name == task)
    for _ in range(rounds):
        loads = [Load(s.name, costs[s.name].seconds, period if s.name == task else s.period, s.critical) for s in specs]
        response = response_times(loads)[task].time
        if response <= period * (1 + 1e-12):
            return period
        if response == float("inf"):
            return None
        period = response
    return None
