"""A subsystem's exclusive devices have one master: a second live run of it is refused."""

from __future__ import annotations

from pbo_runtime.config.model import Subsystem
from pbo_runtime.ipc import runs
from pbo_runtime.supervisor.failures import RunRefused


def refuse_if_devices_in_use(subsystem: Subsystem, run_id: str) -> None:
    """RunRefused if a live run of `subsystem` other than `run_id` holds its exclusive devices.

    Checked before anything starts, and again once the run's table exists, before any child
    starts: two runs started at the same instant then each see the other's table, and at most
    one goes on (both may refuse; neither runs alongside the other). A subsystem without
    exclusive devices may run several times side by side.
    """
    exclusive = [name for name, device in subsystem.devices.items() if device.exclusive]
    if not exclusive:
        return
    others = [run for run in runs.live_runs(subsystem.name) if run.run_id != run_id]
    if not others:
        return
    devices = ", ".join(f"'{name}'" for name in exclusive)
    raise RunRefused(f"subsystem '{subsystem.name}' is already running as {' and '.join(run.brief() for run in others)}, "
                     f"which holds its exclusive device(s) {devices}: a second run would drive them too; "
                     f"stop that run first: pbo stop --run {others[0].run_id}")
