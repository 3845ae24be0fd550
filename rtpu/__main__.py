"""`python -m rtpu`: one emulated real-time processing unit, started by the supervisor.

It loads and checks the same YAML file as the supervisor, attaches to the run's table (the
layout hash proves they agree), hosts the tasks the file assigns to it, and runs the executive
until told to stop. A module that raises never takes this process down (see `Task`). A live
change comes as a `LiveUpdate`: it reads the run's live description (`live-N.json`, plain data
written by job control) and stages it for the next plan.
"""

from __future__ import annotations

from pbo_runtime.objects import dataclass_code

dataclass_code.install()  # before the imports below make their dataclasses (a fork server's: installed already)

import dataclasses
import json
import os
import sys
import traceback
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import posix_ipc

from pbo_runtime.clock.clocks import RealClock, SimClock
from pbo_runtime.clock.lockstep import LockstepParticipant
from pbo_runtime.config.model import DeviceSpec, Subsystem, TaskSpec
from pbo_runtime.edit.wire import task_from_wire
from pbo_runtime.ipc import limits, messages, process
from pbo_runtime.ipc.process import Stop, become_child, stop_only_at_waits
from pbo_runtime.objects import registry
from pbo_runtime.objects.helper_threads import GIL_HANDOVER, lower_helpers
from pbo_runtime.reports.log_notes import run_metadata, variable_notes
from pbo_runtime.supervisor import last_out
from pbo_runtime.supervisor.launch import RtpuLaunch
from pbo_runtime.supervisor.reconfiguration import Reconfiguration
from pbo_runtime.table.table import StateTable, TableLayout
from pbo_runtime.task.lifecycle import Task
from rtpu import _realtime
from rtpu._executive import Executive
from rtpu.plans import LiveStage

if TYPE_CHECKING:
    from pbo_runtime.links.relay import MessageRelay


def main(argv: list[str] | None = None, subsystem: Subsystem | None = None) -> int:
    """Run one RTPU; `subsystem`: the file already loaded and checked (a fork server's), else loaded here."""
    try:
        return _run(argv, subsystem)
    except Stop:  # stopped again while it stopped: a second signal, or the bound once the supervisor died
        return 0
    finally:
        last_out.leave()  # the run's last process out after its supervisor died removes the run


def _run(argv: list[str] | None, subsystem: Subsystem | None) -> int:
    launch = RtpuLaunch.parse(argv, __doc__)
    if launch.parent:
        last_out.expect(launch.run_id)  # (a supervisor that died before this process started leaves it the run's end)
        become_child(launch.parent)
        if not last_out.join(launch.run_id):
            return 3  # the supervisor died and its run was removed before this process started

    if subsystem is None:  # (imported here: a forked RTPU, and its fork server, never load a file)
        from pbo_runtime.config.loader import load_subsystem

        subsystem = load_subsystem(launch.file)
    name = subsystem.name
    events = messages.Queue(messages.event_queue_name(name, launch.run_id))

    def report(event: messages.Event) -> None:
        events.report(launch.rtpu, event)

    # at stop: job control drains its queue while every RTPU reports, so a full queue is waited out
    # (while job control lives: after it was killed nobody drains the queue, and the wait would only hang)
    supervisor_alive = (lambda: os.getppid() == launch.parent) if launch.parent else None

    def report_at_stop(event: messages.Event) -> None:
        events.report(launch.rtpu, event, timeout=5.0, reader_alive=supervisor_alive)

    table = signals = barrier = None
    executive = None
    try:
        table = StateTable.attach(TableLayout.of(subsystem), messages.table_name(name, launch.run_id))
        signals = messages.Queue(messages.signal_queue_name(name, launch.run_id, launch.rtpu))
        hosting = host_tasks(launch, subsystem, table, signals, report, report_at_stop)
        executive = hosting.executive
        simulated = launch.clock == "sim"
        if simulated:
            barrier = LockstepParticipant(name, launch.run_id, launch.rtpu, table.header, list(launch.ring) or [launch.rtpu],
                                          events.pending, before_step=lambda: pump(hosting.pumped))
        if launch.live and not simulated and not launch.restarted:
            registry.import_library()  # a task spawned live finds its module imported (forked: the server did it)
        stop_only_at_waits()  # the executive takes the table lock from here on: a stop must not land inside a transfer
        report(messages.Ready(hosting.realtime))
        if barrier is not None:
            executive.run_lockstep(barrier)
        else:
            executive.run()
        return 0
    except Stop:
        if executive is not None and executive.running:
            executive.stop()
        return 0
    except posix_ipc.SignalError as exc:
        if process.stop_requested():  # a stop signal ended a wait on the table lock, which a wedge held up
            return 0
        report(messages.Crashed(f"{type(exc).__name__}: {exc}", traceback.format_exc()))
        return 1
    except Exception as exc:
        limit = limits.explain(exc, f"{launch.rtpu} starting" if executive is None else launch.rtpu)
        report(messages.Crashed(str(limit), "") if limit is not None
               else messages.Crashed(f"{type(exc).__name__}: {exc}", traceback.format_exc()))
        return 1
    finally:
        if barrier is not None:
            barrier.close()
        if signals is not None:
            signals.close()
        if table is not None:
            table.close()
        events.close()


@dataclasses.dataclass
class Hosting:
    """An RTPU's executive with its tasks added, and what its turns need besides (the simulated clock's relays)."""

    executive: Executive
    pumped: list[MessageRelay]  # the simulated clock's relays: each forwards its link's messages at every step
    realtime: dict[str, Any]  # what it got of the OS (scheduler, CPU), for its Ready event


def host_tasks(launch: RtpuLaunch, subsystem: Subsystem, table: StateTable, signals: messages.Queue,
               report: Callable[[messages.Event], None], report_at_stop: Callable[[messages.Event], None],
               in_process: bool = False) -> Hosting:
    """The executive of RTPU `launch.rtpu` on its attached table, every task it hosts added (not yet spawned);
    `in_process`: hosted in the supervisor's own process (`rtpu.in_process`)."""
    name = subsystem.name
    links = launch.links
    registers = messages.plant_registers_name(name, launch.run_id)
    # drivers that keep figures of their own (a special-purpose processor's timing), by task and
    # device: their figures go with the task's statistics into the run's summary
    with_figures: dict[str, dict[str, Any]] = {}

    def open_device(device: DeviceSpec, task: TaskSpec) -> Any:  # a driver, as `DeviceOpener` says
        # The device database (TR 4.6.1) records the opening in the table, for every RTPU to see.
        from pbo_runtime.table.devices import DeviceDatabase

        driver = DeviceDatabase(subsystem, table, registers).open(device.name, task)
        if callable(getattr(driver, "figures", None)):
            with_figures.setdefault(task.name, {})[device.name] = driver
        return driver

    def device_figures(task: str) -> dict[str, Any]:
        return {device: driver.figures() for device, driver in with_figures.get(task, {}).items()}

    pumped: list[MessageRelay] = []  # the simulated clock's relays: each forwards its link's messages at every step

    def relay(task: str, end: Any) -> MessageRelay:  # `end`: a message link's receiving end
        # A message link's server task (TR 5.1): each message is a signal to this RTPU.
        from pbo_runtime.links.relay import MessageRelay

        made = MessageRelay(end, signals.another_end(), task, threaded=not simulated)
        if simulated:
            pumped.append(made)
        return made

    rtpu = subsystem.rtpu(launch.rtpu)
    # A restarted RTPU spawns its tasks while the other RTPUs run: their inits (imports, models,
    # files) at SCHED_FIFO would hold a CPU the others' cycles need, so it takes SCHED_FIFO only
    # when its first task turns on.
    fifo_later = launch.fifo and launch.restarted
    priority = _realtime.fifo_priority(any(t.critical for t in subsystem.tasks_on(launch.rtpu)))
    # (hosted in the supervisor's process, it asks nothing of the OS: that process is not its own)
    applied = {} if in_process else _realtime.apply(rtpu.cpu, launch.fifo and not fifo_later, priority)
    realtime: dict[str, Any] = {**applied, "spin": f"{launch.spin * 1e6:g} µs"}
    if fifo_later:
        realtime["scheduler"] = f"SCHED_FIFO {priority} from its first task on (restarted: inits at SCHED_OTHER)"
    simulated = launch.clock == "sim"
    if simulated:
        realtime = {"clock": f"simulated, {launch.tick * 1e3:g} ms ticks"}
    if not simulated:
        # A thread of this process holding the GIL (a log's writer, the background work) gives
        # it back within this interval when the executive wakes for a release: the spin covers it.
        sys.setswitchinterval(GIL_HANDOVER)
    clock = SimClock(table.header, launch.tick) if simulated else RealClock(launch.spin)
    # what a data log says of the run and its variables: made once, copied by each task's init
    notes = variable_notes(subsystem)
    about_run = run_metadata(subsystem, launch.clock, launch.configuration, launch.application)

    def factory(spec: TaskSpec) -> Callable[[], Task]:
        module_class = registry.module_class(spec.module)

        def make() -> Task:
            return Task(spec, module_class, table, dict(subsystem.dims), dict(subsystem.devices), open_device,
                        out_dir=launch.out, links=links, relay=relay, run_metadata=about_run, variable_notes=notes,
                        restarted=launch.restarted)

        return make

    def live_stage(sequence: int) -> LiveStage:
        # A live change: the description job control checked, as plain data (edit.live.to_wire),
        # read between cycles. No module is looked up here but for a task this RTPU will spawn or
        # tune (`spec`): the RTPU of a critical task spends well under a millisecond on it.
        with open(os.path.join(launch.live, f"live-{sequence}.json"), encoding="utf-8") as stream:
            data = json.load(stream)
        tasks = data["tasks"]
        reconfiguration = Reconfiguration.of_members(
            data["configurations"], {name: (t["index"], t["period"], t["writes"]) for name, t in tasks.items()})

        def spec(name: str) -> TaskSpec:
            return task_from_wire(subsystem, name, tasks[name])

        def lazy(name: str) -> Callable[[], Task]:
            return lambda: factory(spec(name))()

        return LiveStage(reconfiguration, {name: (t["index"], t["params"]) for name, t in tasks.items()}, spec,
                         {name: lazy(name) for name, t in tasks.items() if t["rtpu"] == launch.rtpu})

    executive = Executive(clock, signals, report, epoch=launch.epoch, header=table.header, report_at_stop=report_at_stop,
                          reconfiguration=Reconfiguration(subsystem), rtpu_index=rtpu.index,
                          n_rtpus=len(subsystem.rtpus), live_loader=live_stage if launch.live else None,
                          cycle_lock_wait=None if simulated else table.cycle_lock_wait)
    executive.device_figures = device_figures
    if fifo_later:
        def take_fifo() -> None:
            _realtime.apply(rtpu.cpu, True, priority)
            lower_helpers()

        executive.before_first_on = take_fifo
    if launch.live_now:  # restarted after live changes: its tasks and configurations are the live description's
        described = live_stage(launch.live_now)
        executive.reconfiguration = described.reconfiguration
        hosted = dict(described.factories)
    else:
        hosted = {spec.name: factory(spec) for spec in subsystem.tasks_on(launch.rtpu)}
    for make in hosted.values():
        executive.add(make(), make)
    return Hosting(executive, pumped, realtime)


def pump(relays: list[MessageRelay]) -> None:
    """Each relay of the simulated clock forwards what its link holds now; a closed one (its task killed) is dropped."""
    if not relays:  # (every tick, and most runs have none)
        return
    for relay in list(relays):
        if relay.closed:
            relays.remove(relay)
        else:
            relay.pump()


if __name__ == "__main__":  # a fresh interpreter (a forked child never saves)
    status = main()
    dataclass_code.save()
    sys.exit(status)
