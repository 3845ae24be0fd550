"""Device driver objects (TR §4.6): how a task reaches hardware, opened by name in `init`.

The runtime builds a driver from the YAML `devices:` entry: the registered driver class gets the
name of the plant's register segment (the simulated board) and the device's options.
"""

from __future__ import annotations

from typing import Any, Mapping


class DeviceDriver:
    """Base of driver objects. Reads and writes must be real-time safe (no allocation)."""

    def __init__(self, registers: str, options: Mapping[str, Any]) -> None:
        self.registers = registers
        self.options = dict(options)

    def close(self) -> None:
        """Release the device; called when the task that opened it is killed."""
