"""What a run's files say about the run and its variables: made once, before any task is made.

A data log carries each variable's doc and unit, and the run's metadata (subsystem,
configuration, clock, versions, the YAML file), so a tool that opens it knows what it holds.
Both are plain strings worked out here from the checked subsystem, so a task's `init` only
copies them (`PortBasedObject.run_metadata`, `variable_note`).

A variable's unit is its object type's `unit:` when it has one, else the last clause of its
`doc:` when that clause is made of units only, as the shipped files write them:
`doc: "measured joint velocity, rad/s"` has unit `rad/s` and doc `measured joint velocity`.
A variable the file declares without a doc (or not at all) takes the doc of the port that
writes it, as its module declares it.
"""

from __future__ import annotations

import functools
import platform
import re
from pathlib import Path

from pbo_runtime.config.model import Subsystem
from pbo_runtime.objects import distributions
from pbo_runtime.objects.registry import installed_version

# Unit symbols a doc's last clause may be made of (SI and the few others control engineers write)
UNIT_SYMBOLS = frozenset((
    "rad", "deg", "m", "mm", "cm", "km", "s", "ms", "us", "µs", "ns", "min", "h", "Hz", "kHz", "N", "kN", "Nm", "kg", "g",
    "A", "mA", "V", "mV", "W", "kW", "J", "Pa", "kPa", "bar", "K", "°C", "px", "pixel", "pixels", "rpm", "count", "counts"))
_UNIT_TOKEN = re.compile(r"[A-Za-zµ°]+|[0-9²³^*/·()\-. ]")


def split_unit(doc: str) -> tuple[str, str]:
    """(doc, unit) of a doc whose last comma clause is a unit ("joint torque command, N m"); else (doc, "")."""
    head, comma, tail = doc.rpartition(",")
    tail = tail.strip()
    if not comma or not tail or not _is_unit(tail):
        return doc, ""
    return head.strip(), tail


def _is_unit(text: str) -> bool:
    tokens = _UNIT_TOKEN.findall(text)
    if "".join(tokens) != text:
        return False
    words = [t for t in tokens if t[0].isalpha() or t[0] in "µ°"]
    return bool(words) and all(word in UNIT_SYMBOLS for word in words)


def variable_notes(subsystem: Subsystem) -> dict[str, tuple[str, str]]:
    """Every variable's (doc, unit), as a log's channels carry them."""
    notes = {}
    port_docs = _port_docs(subsystem)
    for name, variable in subsystem.variables.items():
        doc, unit = split_unit(variable.doc or port_docs.get(name, ""))
        object_type = subsystem.object_types.get(variable.object or "")
        if object_type is not None and object_type.unit:
            unit = object_type.unit
        notes[name] = (doc, unit)
    return notes


def _port_docs(subsystem: Subsystem) -> dict[str, str]:
    """For a variable the file gives no doc: the doc of a port that writes it (else of one that reads
    it), as the module declares it ("measured joint position, rad")."""
    docs: dict[str, str] = {}
    for writers_first in (True, False):
        for task in subsystem.tasks.values():
            for binding in task.bindings:
                writes = binding.port.kind.value.startswith("out")
                if binding.port.doc and writes == writers_first and binding.variable not in docs:
                    docs[binding.variable] = binding.port.doc
    return docs


def run_metadata(subsystem: Subsystem, clock: str, configuration: str = "", application: str = "") -> dict[str, str]:
    """The run's metadata: what it ran, on which clock, with which versions, from which file (its text included).

    Nothing that differs between two runs of one file (no run id, no date): two runs on the
    simulated clock write identical logs, byte for byte."""
    try:
        text = Path(subsystem.file).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        text = ""
    return {
        "subsystem": subsystem.name, "configuration": configuration or next(iter(subsystem.configurations), ""),
        "application": application, "clock": clock,
        "file": str(Path(subsystem.file).resolve()), "yaml": text,
        "pbo-runtime": installed_version(), "numpy": _version("numpy"), "mujoco": _version("mujoco"),
        "python": platform.python_version(),
    }


@functools.cache  # read once per process
def _version(package: str) -> str:
    return distributions.version(package) or "not installed"
