"""Device driver objects (TR §4.6): how a task reaches hardware, opened by name in `init`.

The runtime builds a driver from the YAML `devices:` entry through the device database
(`table.devices`): the registered driver class gets the name of the plant's register segment (the
simulated board) and the device's options, and, by what the class declares:

- a reconfigurable I/O device driver (TR §4.6.1: an ADC, a DAC, a parallel port) declares
  `PORTS`, its number of channels, and gets `channels=`: the subset the task opened (every
  channel when the task named none). It must touch no other channel: the database lends the
  others to other tasks.
- a sensor-actuator driver (TR §4.6.2: a force/torque sensor) declares `IO`, the kind of I/O
  device it is wired to, and gets `io=`: that device's driver, already opened on the channels the
  YAML's `io: {device: ..., channels: ...}` names. It closes it in its own `close`.
- any other driver (the arm, the camera) gets the registers and the options only.

A driver whose `__init__` takes `device=` also gets the device's YAML name (the trackball names
its operator input after it).

A driver whose `close` waits (for a process it started to exit, a thread to end) closes in two
steps, `close_now` and the rest it returns: a task killed live then holds no cycle of its RTPU.

A driver checks its options in `check_options`, which the checker also calls, so `pbo check`
reports a bad option with the device's YAML location before anything runs.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, ClassVar


class DeviceDriver:
    """Base of driver objects. Reads and writes must be real-time safe (no allocation)."""

    PORTS: ClassVar[int] = 0  # > 0: a port-based I/O device with this many channels (0 .. PORTS-1)
    # The kind of device it drives ("adc", "arm", "camera", "spp"): a sensor's `IO` and a module's
    # DEVICES name it, so `pbo check` refuses a device of the wrong kind before anything opens it
    KIND: ClassVar[str] = ""
    # The names of the options it takes (the YAML keys beside driver, exclusive, io); None: not
    # declared, any (its `check_options` decides). `pbo check` and `pbo lexicon --drivers` read them.
    OPTIONS: ClassVar[tuple[str, ...] | None] = None
    # What it opens besides the device: True when it attaches to the plant's register segment (the
    # simulated hardware), so a task opening it needs a `plant:`; and the plant options it reads
    # (the camera sees the plant's `target`). `pbo check` refuses a file that lacks them (E611).
    NEEDS_PLANT: ClassVar[bool] = False
    PLANT_OPTIONS: ClassVar[tuple[str, ...]] = ()
    IO: ClassVar[str] = ""  # a sensor-actuator driver: the KIND of I/O device it is wired to
    IO_CHANNELS: ClassVar[int] = 0  # ... and how many of its channels it needs
    # The options a device has when its YAML leaves them out: what `pbo check` compares with what
    # a module needs of the device (a module's DEVICES)
    OPTION_DEFAULTS: ClassVar[Mapping[str, Any]] = {}

    def __init__(self, registers: str, options: Mapping[str, Any], *, channels: tuple[int, ...] | None = None,
                 io: DeviceDriver | None = None) -> None:
        self.registers = registers
        self.options = dict(options)
        self.channels: tuple[int, ...] = tuple(channels if channels is not None else range(self.PORTS))
        self.io = io

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> None:
        """Raise ValueError saying what is wrong with `options` (the YAML keys besides driver, exclusive, io)."""

    def close(self) -> None:
        """Release the device; called when the task that opened it is killed."""

    def close_now(self) -> Callable[[], None] | None:
        """Close what must close at once, and return the rest of closing, the part that waits (a
        process's exit, a thread's join), or None when nothing is left.

        A task's kill runs between two cycles of its RTPU: the runtime calls this there and hands
        the rest to the RTPU's background thread. Once this returns, the device may be opened
        again (a task spawned anew): stop it and let go of every name it holds here. The
        default is `close`, all of it now."""
        self.close()
        return None
