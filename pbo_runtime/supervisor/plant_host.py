"""`python -m pbo_runtime.supervisor.plant_host`: the plant process, the physical world outside the subsystem.

It builds the registered plant (e.g. the MuJoCo arm) and steps it once per timestep of wall
time on absolute deadlines; if it falls behind it catches up with extra steps, so simulated
time tracks wall time, and counts the steps that were late. A plant under SCHED_FIFO that falls
`BEHIND_LIMIT` behind cannot keep up (a step takes longer than its timestep): catching up would
hold a CPU above every RTPU for good, so it steps down to SCHED_OTHER and says so at the end.
A plant whose process did not run at all for `STALL_AFTER` (stopped, or starved) is another
matter: it resynchronises to wall time instead of integrating the backlog (thousands of steps
of the last command, at once), and reports the stall when it resumes.
With `--clock sim` it steps exactly once per tick of the supervisor's simulated clock instead
(`clock.lockstep`), first in each tick.
"""

from __future__ import annotations

from pbo_runtime.objects import dataclass_code

dataclass_code.install()  # before the imports below make their dataclasses (a fork server's: installed already)

import argparse
import contextlib
import inspect
import json
import os
import sys
import time
import traceback
from typing import Any

import numpy as np

from pbo_runtime.clock.clocks import lower_timer_slack
from pbo_runtime.clock.lockstep import LockstepParticipant
from pbo_runtime.errors import ModuleError
from pbo_runtime.ipc import limits, messages, shm
from pbo_runtime.ipc.process import Stop, become_child, supervisor_told_gone
from pbo_runtime.objects import registry
from pbo_runtime.supervisor import last_out
from pbo_runtime.table.table import HEADER_WORDS

PLANT_FIFO_PRIORITY = 60  # above the RTPUs' 50: the simulated world steps on time whatever they do
BEHIND_LIMIT = 0.1  # seconds behind wall time at which a SCHED_FIFO plant gives up its priority
# Seconds the process may not run between two steps before it counts as stalled (not slow): a
# stopped or starved plant resumes at wall time; the world stood still meanwhile.
STALL_AFTER = 0.02


def main(argv: list[str] | None = None) -> int:
    try:
        return _run(argv)
    except Stop:  # stopped again while it stopped: a second signal, or the bound once the supervisor died
        return 0
    finally:
        last_out.leave()  # the run's last process out after its supervisor died removes the run


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m pbo_runtime.supervisor.plant_host")
    parser.add_argument("--type", required=True)
    parser.add_argument("--model", required=True)
    parser.add_argument("--timestep", type=float, required=True)
    parser.add_argument("--options", default="{}", help="JSON mapping of plant options")
    parser.add_argument("--subsystem", required=True)
    parser.add_argument("--run-id", required=True)
    parser.add_argument("--parent", type=int, default=0)
    parser.add_argument("--fifo", action="store_true", help="SCHED_FIFO above the RTPUs: the world does not wait")
    parser.add_argument("--clock", choices=("real", "sim"), default="real", help="sim: one step per supervisor tick")
    parser.add_argument("--ring", default="plant", help="sim: the participants of a tick, in order (clock.lockstep)")
    parser.add_argument("--out", default="", help="the run's output directory: the plant's own log goes there")
    parser.add_argument("--base-dir", default="", help="the YAML file's folder: a robot file's path is relative to it")
    parser.add_argument("--drivers", default=None,
                        help="the drivers of the subsystem's devices, comma-separated: the plant serves its I/O boards "
                             "only if one of them is a board (default: serve them)")
    return parser.parse_args(argv)


def _has_boards(drivers: str | None) -> bool:
    """Whether the subsystem's devices (`--drivers`) may include a port-based I/O device, a board the plant
    serves (a driver that cannot be looked up may: its task reports why it cannot open it)."""
    if drivers is None:
        return True
    for name in filter(None, drivers.split(",")):
        try:
            if getattr(registry.driver_class(name), "PORTS", 0) > 0:
                return True
        except ModuleError:
            return True
    return False


def _make_plant(args: argparse.Namespace) -> Any:
    """The registered plant the arguments name, on the run's registers."""
    plant_class = registry.plant_class(args.type)
    # A plant that keeps a log of its own (MuJoCo's) takes the run's output directory for it;
    # one that reads files (a robot's) takes the YAML file's folder, where relative paths start.
    parameters = inspect.signature(plant_class).parameters
    return plant_class(
        messages.plant_registers_name(args.subsystem, args.run_id), args.model, args.timestep, json.loads(args.options),
        **({"log_dir": args.out} if "log_dir" in parameters else {}),
        **({"base_dir": args.base_dir} if "base_dir" in parameters and args.base_dir else {}),
        **({"boards": _has_boards(args.drivers)} if "boards" in parameters else {}),
    )


def _stats(plant: Any, steps: int, late: int = 0, stalls: int = 0, stalled_for: float = 0.0,
           behind_when_stepped_down: float = 0.0) -> messages.PlantStats:
    return messages.PlantStats({"steps": steps, "late": late, "stalls": stalls, "stalled_for": stalled_for,
                                "watchdog_trips": getattr(plant, "watchdog_trips", 0),
                                "left_fifo_behind": behind_when_stepped_down})


def _run(argv: list[str] | None) -> int:
    args = _arguments(argv)
    if args.parent:
        last_out.expect(args.run_id)  # (a supervisor that died before this process started leaves it the run's end)
        become_child(args.parent)
        if not last_out.join(args.run_id) and os.getppid() != args.parent:
            return 3  # the supervisor died and its run was removed before this process started
        # (a live parent without a run's table: a plant on its own, as the benchmarks' bare loop runs it)
    lower_timer_slack()
    if args.fifo:
        # the RTPUs report whether SCHED_FIFO was granted; the plant then runs as they do
        with contextlib.suppress(OSError, AttributeError):
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(PLANT_FIFO_PRIORITY))
    events = messages.Queue(messages.event_queue_name(args.subsystem, args.run_id))
    plant = barrier = None
    steps = late = stalls = 0
    stalled_for = 0.0  # seconds of wall time the plant did not integrate (its stalls)
    behind_when_stepped_down = 0.0  # seconds behind wall time when it left SCHED_FIFO (0: it did not)
    try:
        plant = _make_plant(args)
        if args.clock == "sim":
            table = shm.attach_segment(messages.table_name(args.subsystem, args.run_id))
            header = np.frombuffer(table, dtype=np.int64, count=HEADER_WORDS)
            barrier = LockstepParticipant(args.subsystem, args.run_id, "plant", header, args.ring.split(","), events.pending)
        events.report("plant", messages.Ready())
        if barrier is not None:
            while True:
                if barrier.wait():
                    plant.step()
                    steps += 1
                barrier.done()
        dt = plant.timestep
        stall_after = max(STALL_AFTER, 2 * dt)
        next_step = awake = time.monotonic()
        fifo = os.sched_getscheduler(0) == os.SCHED_FIFO
        while True:
            now = time.monotonic()
            if now < next_step:
                time.sleep(next_step - now)
                now = time.monotonic()  # (a process stopped in its sleep wakes up late)
            # Stalled: this process did not run between two wake-ups, wherever a stop landed (in
            # its sleep, its step, or between the two); the time since its last step would miss a
            # stop that landed before that step.
            gap, awake = now - awake, now
            if now - next_step > dt:
                if gap > stall_after and now - next_step > stall_after:
                    events.report("plant", messages.PlantStalled(gap, getattr(plant, "sim_time", 0.0)))
                    resumed = time.monotonic()  # (a stop may land in the report too)
                    stalls += 1
                    stalled_for += resumed - next_step
                    next_step = awake = resumed  # resynchronise: the backlog is not integrated
                else:
                    late += 1
                    if fifo and now - next_step > BEHIND_LIMIT:
                        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
                        fifo = False
                        behind_when_stepped_down = now - next_step
            plant.step()
            steps += 1
            next_step += dt
    except Stop:
        return 0
    except Exception as exc:
        limit = limits.explain(exc, "the plant")
        events.report("plant", messages.Crashed(str(limit), "") if limit is not None
                      else messages.Crashed(f"{type(exc).__name__}: {exc}", traceback.format_exc()))
        return 1
    finally:
        events.report("plant", _stats(plant, steps, late, stalls, stalled_for, behind_when_stepped_down),
                      reader_alive=lambda: not supervisor_told_gone())
        if barrier is not None:
            barrier.close()
        if plant is not None:
            plant.close()
        events.close()


class HostedPlant:
    """The plant in the supervisor's own process (`--clock sim --one-process`): one step per tick, called
    by the one process's ring where the plant's process would have been woken (`rtpu.in_process` says why)."""

    def __init__(self, plant: Any, events: messages.Queue) -> None:
        self.plant = plant
        self.events = events
        self.steps = 0
        self.returncode: int | None = None

    def step(self, new_tick: bool) -> None:
        if new_tick and self.returncode is None:
            try:
                self.plant.step()
            except Exception as exc:
                self.events.report("plant", messages.Crashed(f"{type(exc).__name__}: {exc}", traceback.format_exc()))
                self.terminate(1)
                return
            self.steps += 1

    def poll(self) -> int | None:
        return self.returncode

    def terminate(self, code: int = 0) -> None:
        """Stop as its process does at the end of a run: its figures reported, the plant closed."""
        if self.returncode is None:
            self.returncode = code
            self.events.report("plant", _stats(self.plant, self.steps))
            self.plant.close()


def in_process(argv: list[str], events: messages.Queue) -> HostedPlant:
    """The plant `python -m pbo_runtime.supervisor.plant_host ARGV --clock sim` runs, hosted in this process."""
    plant = _make_plant(_arguments(argv))
    events.report("plant", messages.Ready())
    return HostedPlant(plant, events)


if __name__ == "__main__":  # a fresh interpreter (a forked child never saves)
    status = main()
    dataclass_code.save()
    sys.exit(status)
