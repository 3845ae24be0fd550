"""The device database (TR §4.6.1): which task holds which device, and which of its channels.

A task opens its devices in `init`, on whatever RTPU hosts it. The database builds the driver
object there (drivers float to any RTPU) and records the opening in the run's state table, so
every RTPU process sees the same ownership, guarded by the table's one lock:

- an exclusive device has one holder: a second task opening it is refused, naming the holder;
- a shared port-based I/O device (an ADC, a DAC, a parallel port) lends channel subsets: a
  task that opens `{device: adc0, channels: 0-5}` holds channels 0-5, another may hold 6-7, and an
  overlapping request is refused, naming who holds which channels. A task that names no channels
  opens every channel of a port-based device;
- a sensor-actuator device wired to an I/O device (`io: {device: adc0, channels: 0-5}`, TR §4.6.2)
  also takes those channels for the task that opens the sensor;
- a shared device that is not port-based (a camera) locks nothing.

An opening is released when the driver is closed (the task is killed, or its init failed). The
records of a process that died (an RTPU killed with its tasks) are recovered by the next opening
that finds them in its way. Adding a device is a change to the YAML only: the database is driven
by `devices:` and each task's `resources:`.

Nothing here is on the per-cycle path: opening happens in `init`; the driver it returns moves the
data with views it precomputed.
"""

from __future__ import annotations

import inspect
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pbo_runtime.config.channels import channels_of, format_channels, mask_of
from pbo_runtime.config.model import DeviceSpec, Subsystem, TaskSpec
from pbo_runtime.errors import PboError
from pbo_runtime.ipc.shm import pid_alive
from pbo_runtime.objects import registry
from pbo_runtime.table.table import DEVICE_HOLDERS, Holder, StateTable

DriverLookup = Callable[[str], Any]


class DeviceOpenError(PboError):
    """A device cannot be opened as the task asks (its channels, its wiring, its driver)."""


class DeviceBusyError(DeviceOpenError):
    """Another task holds the device, or some of the channels asked for."""


@dataclass(frozen=True)
class Opening:
    """One device an opening takes: the device, its driver class and the channels held (None: none locked)."""

    device: DeviceSpec
    driver: type
    channels: tuple[int, ...] | None


@dataclass(frozen=True)
class HolderRecord:
    """Who holds a device, as the table records it (for tools and tests)."""

    device: str
    task: str
    rtpu: str
    pid: int
    channels: tuple[int, ...]
    exclusive: bool
    opened: str  # the device the task opened: differs from `device` for a sensor's io:

    def describe(self) -> str:
        held = f"channels {format_channels(self.channels)}" if self.channels else "it"
        through = f" through device '{self.opened}'" if self.opened != self.device else ""
        return f"task '{self.task}' (RTPU {self.rtpu}, pid {self.pid}) holds {held}{through}"


class DeviceDatabase:
    """Opens devices for tasks and keeps who holds what in the table's device region."""

    def __init__(self, subsystem: Subsystem, table: StateTable, registers: str,
                 driver_lookup: DriverLookup = registry.driver_class) -> None:
        self.subsystem = subsystem
        self.table = table
        self.registers = registers
        self.driver_lookup = driver_lookup
        self._index = {name: i for i, name in enumerate(subsystem.devices)}
        self._names = list(subsystem.devices)
        self._tasks = {t.index: t for t in subsystem.tasks.values()}
        self._pid = os.getpid()

    # --- opening ---------------------------------------------------------------------------

    def plan(self, name: str, task: TaskSpec) -> list[Opening]:
        """What opening device `name` for `task` takes: the device, then each I/O device under it."""
        devices = self.subsystem.devices
        if name not in devices:
            raise DeviceOpenError(f"no device '{name}' (devices: {', '.join(devices) or 'none'})")
        if name not in task.resources:
            listed = ", ".join(task.resources) or "none"
            raise DeviceOpenError(f"task '{task.name}' opens device '{name}', but its resources are: {listed}")
        spec = devices[name]
        channels = task.resource_channels.get(name)
        openings: list[Opening] = []
        while True:
            driver = self.driver_lookup(spec.driver)
            ports = int(getattr(driver, "PORTS", 0))
            if channels is not None:
                if ports == 0:
                    raise DeviceOpenError(
                        f"device '{spec.name}' (driver {spec.driver}) is not a port-based I/O device: it has no channels "
                        f"to open, asked for {format_channels(channels)}; list it without channels")
                missing = [c for c in channels if c >= ports]
                if missing:
                    raise DeviceOpenError(
                        f"device '{spec.name}' (driver {spec.driver}) has channels 0-{ports - 1}; "
                        f"channel(s) {format_channels(missing)} do not exist")
            held = channels if channels is not None else (tuple(range(ports)) if ports else None)
            openings.append(Opening(spec, driver, held))
            if spec.io is None:
                return openings
            if spec.io.device not in devices or any(o.device.name == spec.io.device for o in openings):
                raise DeviceOpenError(
                    f"device '{spec.name}' is wired (io:) to '{spec.io.device}', which is not an I/O device of this subsystem"
                )
            io = spec.io
            spec, channels = devices[io.device], io.channels

    def open(self, name: str, task: TaskSpec) -> Any:
        """Claim device `name` (and what it is wired to) for `task`, then build its driver.

        Raises DeviceBusyError naming the holder if another task holds it, DeviceOpenError for
        a channel or wiring the device does not have. The driver's `close` releases the claim.
        """
        openings = self.plan(name, task)
        records = self._claim(task, openings)
        try:
            driver = self._build(openings)
        except BaseException:
            self._release(records, task)
            raise
        close, close_now = driver.close, getattr(driver, "close_now", None)
        released = False

        def release() -> None:
            nonlocal released
            if not released:
                released = True
                self._release(records, task)

        def close_and_release() -> None:
            try:
                close()
            finally:
                release()

        def close_now_and_release() -> Any:
            assert close_now is not None
            try:
                return close_now()  # the rest of closing (a process's exit waited for) needs no claim
            finally:
                release()

        driver.close = close_and_release  # the task closes what it opened when it is killed
        if close_now is not None:
            driver.close_now = close_now_and_release
        return driver

    def _build(self, openings: list[Opening]) -> Any:
        """The drivers, I/O device first: each sensor gets the one under it as `io=`."""
        below = None
        try:
            for opening in reversed(openings):
                kwargs: dict[str, Any] = {}
                if getattr(opening.driver, "PORTS", 0):
                    kwargs["channels"] = opening.channels
                if opening.device.io is not None:
                    kwargs["io"] = below
                if "device" in inspect.signature(opening.driver).parameters:  # a driver that names what it makes after its device
                    kwargs["device"] = opening.device.name
                driver = opening.driver(self.registers, opening.device.options, **kwargs)
                below = driver
        except BaseException:
            if below is not None:  # the sensor that would have owned it never came to be
                below.close()
            raise
        return below

    # --- ownership in the table ------------------------------------------------------------

    def _claim(self, task: TaskSpec, openings: list[Opening]) -> list[tuple[int, int]]:
        """Record the openings under the table lock; (device, slot) of each record written."""
        table = self.table
        devices = table.devices
        opened = self._index[openings[0].device.name] + 1
        written: list[tuple[int, int]] = []
        table.acquire()
        try:
            for opening in openings:
                blocking = self._blocking(task, opening)
                if blocking:
                    raise DeviceBusyError(self._busy_message(task, openings[0].device.name, opening, blocking))
            for opening in openings:
                d = self._index[opening.device.name]
                free = next((r for r in range(DEVICE_HOLDERS) if devices[d, r, Holder.TASK] == 0), None)
                if free is None:
                    raise DeviceBusyError(
                        f"device '{opening.device.name}' is open {DEVICE_HOLDERS} times already, the most the device "
                        f"database records; task '{task.name}' cannot open it too")
                record = devices[d, free]
                record[Holder.PID] = self._pid
                record[Holder.MASK] = mask_of(opening.channels or ())
                record[Holder.EXCLUSIVE] = int(opening.device.exclusive)
                record[Holder.OPENED] = opened
                record[Holder.TASK] = task.index + 1
                written.append((d, free))
        except BaseException:
            for d, r in written:
                devices[d, r] = 0
            raise
        finally:
            table.release()
        return written

    def _blocking(self, task: TaskSpec, opening: Opening) -> list[HolderRecord]:
        """The live holders that stand in the way of `opening` (dead processes' records are freed). Under the lock."""
        d = self._index[opening.device.name]
        mask = mask_of(opening.channels or ())
        found = []
        for record in self.table.devices[d]:
            holder = int(record[Holder.TASK]) - 1
            if holder < 0 or holder == task.index:
                continue  # free, or the task's own (a task may open a device twice)
            held = int(record[Holder.MASK])
            if not (opening.device.exclusive or record[Holder.EXCLUSIVE] or held & mask):
                continue
            if not pid_alive(int(record[Holder.PID])):
                record[:] = 0  # its RTPU died with the task: recover the device
                continue
            found.append(self._describe(d, record))
        return found

    def _busy_message(self, task: TaskSpec, name: str, opening: Opening, holders: list[HolderRecord]) -> str:
        device = opening.device.name
        who = "; ".join(h.describe() for h in holders)
        if name != device:
            asked = f"device '{name}', wired to channels {format_channels(opening.channels or ())} of device '{device}'"
        elif opening.channels:
            asked = f"channels {format_channels(opening.channels)} of device '{device}'"
        else:
            asked = f"device '{device}'"
        if opening.device.exclusive or any(h.exclusive for h in holders):
            return (f"task '{task.name}' cannot open {asked}: the device is exclusive and {who}; "
                    "an exclusive device has one user at a time (turn the holder off and kill it first)")
        overlap = set(opening.channels or ()) & {c for h in holders for c in h.channels}
        return (f"task '{task.name}' cannot open {asked}: {who}; they overlap on {format_channels(overlap)}; "
                "a channel has one user at a time: give the tasks disjoint channels in their resources")

    def _release(self, records: list[tuple[int, int]], task: TaskSpec) -> None:
        table = self.table
        if table.devices is None:  # the table was closed first (the process is stopping)
            return
        table.acquire()
        try:
            for d, r in records:
                record = table.devices[d, r]
                if record[Holder.TASK] == task.index + 1 and record[Holder.PID] == self._pid:
                    record[:] = 0
        finally:
            table.release()

    # --- for tools -------------------------------------------------------------------------

    def holders(self) -> list[HolderRecord]:
        """Every record of the device region, read under the lock."""
        table = self.table
        table.acquire()
        try:
            found = [self._describe(d, record) for d in range(len(self._names)) for record in table.devices[d]
                     if record[Holder.TASK]]
        finally:
            table.release()
        return found

    def _describe(self, d: int, record: Any) -> HolderRecord:
        index = int(record[Holder.TASK]) - 1
        task = self._tasks.get(index)
        opened = int(record[Holder.OPENED]) - 1
        return HolderRecord(
            device=self._names[d],
            task=task.name if task else f"#{index}",
            rtpu=task.rtpu if task else "?",
            pid=int(record[Holder.PID]),
            channels=channels_of(int(record[Holder.MASK])),
            exclusive=bool(record[Holder.EXCLUSIVE]),
            opened=self._names[opened] if 0 <= opened < len(self._names) else self._names[d],
        )

