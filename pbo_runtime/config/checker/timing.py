"""Timing across tasks: schedulability of each RTPU's load, RTPU spins, and the order in which
tasks must start so each const is written before it is read.
"""

from __future__ import annotations

import graphlib
import heapq
import itertools
from collections.abc import Sequence

from pbo_runtime.config.checker.base import CheckerBase
from pbo_runtime.config.checker.model import _Task
from pbo_runtime.config.checker.words import _ms
from pbo_runtime.config.model import NOWHERE


class TimingChecks(CheckerBase):
    """Rules that look at every task's timing or const ports at once."""

    def check_spins(self) -> None:
        """E509: an RTPU's spin before a release must be shorter than its shortest period, or it
        never sleeps: it would spin through every period, a whole CPU for nothing."""
        shortest: dict[str, _Task] = {}
        for task in self.tasks.values():
            if (task.rtpu and task.period > 0 and not task.aperiodic
                    and (task.rtpu not in shortest or task.period < shortest[task.rtpu].period)):
                shortest[task.rtpu] = task
        for rtpu in self.out.rtpus:
            fastest = shortest.get(rtpu.name)
            if fastest is not None and rtpu.spin >= fastest.period:
                self.error(
                    "E509",
                    f"spin of RTPU '{rtpu.name}' must be shorter than the shortest period of its tasks "
                    f"({_ms(fastest.period)}, task '{fastest.name}'), got: {_ms(rtpu.spin)}",
                    rtpu.spin_loc,
                    "the executive sleeps until `spin` before each release and spins the rest; "
                    "the default, 200 us, hid the wake-up latency of the machine in docs/performance.md; "
                    "`python -m bench.wait` measures yours",
                )

    def check_simulation_grid(self) -> None:
        """W504: `pbo run --clock sim` steps the plant and releases tasks on its timestep, so it refuses
        a period that is not a whole multiple of it; the real clock runs the file."""
        plant = self.out.plant
        if plant is None or plant.timestep is None or plant.timestep <= 0:
            return
        tick_ns = round(plant.timestep * 1e9)
        for task in self.out.tasks.values():
            ns = round(task.period * 1e9)
            if tick_ns and ns % tick_ns:
                self.warn(
                    "W504",
                    f"period of task '{task.name}' ({_ms(task.period)}) is not a whole multiple of the plant's "
                    f"timestep ({_ms(plant.timestep)}): pbo run --clock sim refuses the file",
                    task.loc,
                    f"make it a multiple of {_ms(plant.timestep)} to run it on the simulated clock (the real clock runs it)",
                )

    def check_schedulability(self) -> None:
        """Warn where the declared wcets of one RTPU's tasks in a configuration cannot be guaranteed.

        Only tasks that declare `wcet:` count; an aperiodic task counts at its min_interarrival
        (a sporadic task at its fastest). For each RTPU and configuration, with U = Σ wcet_i / T_i
        over its n tasks:

        - U > 1 (W502): overloaded; no scheduler meets every deadline.
        - else U > n(2^(1/n) - 1) (W501): beyond Liu & Layland's rate-monotonic bound, so
          fixed rate-monotonic priorities are not guaranteed (the test is sufficient, not necessary).
        - the critical tasks, U_c > 1 (W503): the executive runs maximum-urgency-first (Stewart &
          Khosla): critical tasks always before the others, earliest deadline first among them.
          With EDF inside the critical set, MUF guarantees that set when it fits the processor
          on its own, U_c <= 1. We apply that test, not the RM bound n_c(2^(1/n_c) - 1), because
          the executive orders critical tasks by deadline, not by rate. It ignores blocking: the
          executive does not preempt a cycle, so a long non-critical cycle can still delay a
          critical release by up to its wcet.
        """
        seen: set[tuple[str, frozenset[str]]] = set()
        for config, members in self.config_members.items():
            by_rtpu: dict[str, list[_Task]] = {}
            for task_name, _ in members:
                task = self.tasks.get(task_name)
                if task is not None and task.rtpu and task.period > 0:
                    by_rtpu.setdefault(task.rtpu, []).append(task)
            loc = self.config_locs.get(config, NOWHERE)
            for rtpu, tasks in by_rtpu.items():
                timed = [t for t in tasks if t.wcet is not None]
                key = (rtpu, frozenset(t.name for t in timed))
                if not timed or key in seen:
                    continue
                seen.add(key)
                untimed = [t.name for t in tasks if t.wcet is None]
                note = f"; tasks without a wcet ({', '.join(untimed)}) only add to it" if untimed else ""
                total = sum(_utilisation(t) for t in timed)
                n = len(timed)
                bound = n * (2 ** (1 / n) - 1)
                where = f"RTPU '{rtpu}' in configuration '{config}'"
                if total > 1:
                    self.warn(
                        "W502",
                        f"{where} is overloaded: {_loads(timed)}; U = {total:.3f} > 1",
                        loc,
                        "no schedule meets every deadline; move a task to another RTPU, lengthen a period or shorten a cycle"
                        + note,
                    )
                elif total > bound:
                    self.warn(
                        "W501",
                        f"{where} exceeds the rate-monotonic bound: {_loads(timed)}; U = {total:.3f} "
                        f"> {bound:.3f} = n(2^(1/n) - 1) for n = {n}",
                        loc,
                        "Liu & Layland's test cannot guarantee these deadlines (it is sufficient, not necessary); "
                        "move a task to another RTPU or lengthen a period" + note,
                    )
                critical = [t for t in tasks if t.critical]
                if critical and all(t.wcet is not None for t in critical):
                    critical_total = sum(_utilisation(t) for t in critical)
                    if critical_total > 1:
                        self.warn(
                            "W503",
                            f"critical tasks of {where} are not guaranteed: {_loads(critical)}; U_critical = "
                            f"{critical_total:.3f} > 1",
                            loc,
                            "maximum-urgency-first (Stewart & Khosla) guarantees the critical set only when it fits the RTPU "
                            "on its own (EDF within the set); make fewer tasks critical, or spread them over RTPUs",
                        )

    def check_const_order(self) -> None:
        """Producers of consts start before their readers, across every task; a cycle is an error."""
        tasks = [t for t in self.tasks.values() if t.ok]
        producers: dict[str, list[_Task]] = {}
        for task in tasks:
            for b in task.bindings:
                if b.port.kind.supplies_initial_value:
                    producers.setdefault(b.variable, []).append(task)
        graph: dict[str, set[str]] = {t.name: set() for t in tasks}
        via: dict[tuple[str, str], str] = {}
        for task in tasks:
            for b in task.bindings:
                if b.port.kind.needs_initial_value:
                    for producer in producers.get(b.variable, []):
                        graph[task.name].add(producer.name)
                        via.setdefault((producer.name, task.name), b.variable)
        order = _init_order(graph, {t.name: t.index for t in tasks})
        if order is not None:
            self.out.init_order = order
            return
        sorter = graphlib.TopologicalSorter(graph)  # a cycle: graphlib's search finds one to report
        try:
            sorter.prepare()
        except graphlib.CycleError as exc:
            cycle: list[str] = list(exc.args[1])
            links = "; ".join(
                f"'{a}' writes '{via.get((a, b), '?')}' that '{b}' reads before its init" for a, b in itertools.pairwise(cycle)
            )
            self.error(
                "E406",
                f"const dependencies form a cycle: {' -> '.join(cycle)}",
                self.tasks[cycle[0]].loc,
                f"{links}; break the cycle by making one of these ports a var (in-var/out-var)",
            )
            return
        raise AssertionError("the init order found a cycle that graphlib does not")  # the checker reports it as E901


def _init_order(graph: dict[str, set[str]], index: dict[str, int]) -> tuple[str, ...] | None:
    """Each task after the producers it reads consts from (`graph`: task -> those producers), the
    first written (`index`) first among those ready; None when there is a cycle.

    The order graphlib.TopologicalSorter gives when each ready task is taken in file order, found
    without its Python-level bookkeeping per node (a large file has tens of thousands of tasks).
    """
    waiting = {name: len(needs) for name, needs in graph.items() if needs}
    readers: dict[str, list[str]] = {}
    for name, needs in graph.items():
        for producer in needs:
            readers.setdefault(producer, []).append(name)
    ready = [(index[name], name) for name in graph if name not in waiting]
    heapq.heapify(ready)
    order: list[str] = []
    while ready:
        _, name = heapq.heappop(ready)
        order.append(name)
        for reader in readers.get(name, ()):
            waiting[reader] -= 1
            if not waiting[reader]:
                heapq.heappush(ready, (index[reader], reader))
    return tuple(order) if len(order) == len(graph) else None


def _utilisation(task: _Task) -> float:
    return (task.wcet or 0.0) / task.period


def _loads(tasks: Sequence[_Task]) -> str:
    """'traj 0.400 (0.8 ms / 2 ms), pid 0.500 (0.5 ms / 1 ms)'."""
    return ", ".join(f"{t.name} {_utilisation(t):.3f} ({_ms(t.wcet or 0.0)} / {_ms(t.period)})" for t in tasks)
