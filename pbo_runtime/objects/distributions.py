"""Installed distributions' entry points and versions, read from their metadata folders on sys.path.

What `importlib.metadata` reads, by its rules, without importing it: its import (the email
package, zipfile, csv and more) costs more than the reading, and every `pbo check`, every `pbo
run` and its fork server look up the library. The rules kept: each `*.dist-info` or `*.egg-info`
folder of each sys.path entry in turn; of two distributions with the same normalized name the
first found wins; `entry_points.txt` is read as `importlib.metadata` reads it (sections are
groups, `name = value` lines, `#` comments); an entry point loads as `module:attr.attr`.
Distributions inside zip files or eggs are not seen (none of pbo's libraries installs so).
`pbo --version` reads its version here too: this module imports nothing more than os and sys.
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Iterator

_INFO_SUFFIXES = (".dist-info", ".egg-info")
_VALUE = r"(?P<module>[\w.]+)\s*(:\s*(?P<attr>[\w.]+)\s*)?((?P<extras>\[.*\])\s*)?$"  # importlib.metadata's


class EntryPoint:
    """One `name = module:attr` line of a distribution's `entry_points.txt`, under `group`."""

    __slots__ = ("group", "name", "value")

    def __init__(self, name: str, value: str, group: str) -> None:
        self.name, self.value, self.group = name, value, group

    def __repr__(self) -> str:
        return f"EntryPoint({self.name!r}, {self.value!r}, {self.group!r})"

    def load(self) -> object:
        """The module, or the object named in it (ValueError for a value that names neither)."""
        import importlib
        import re

        match = re.match(_VALUE, self.value)
        if match is None:
            raise ValueError(f"entry point {self.name} = {self.value!r} names no module")
        found: object = importlib.import_module(match.group("module"))
        for attr in filter(None, (match.group("attr") or "").split(".")):
            found = getattr(found, attr)
        return found


def normalized(name: str) -> str:
    """A distribution's name as packaging compares names (PEP 503, with underscores): each run of
    `-`, `_` and `.` is one `_`."""
    kept: list[str] = []
    for char in name.lower():
        if char not in "-_.":
            kept.append(char)
        elif not kept or kept[-1] != "_":
            kept.append("_")
    return "".join(kept)


@functools.cache  # read once per process: a forked child has it from its parent
def metadata_folders() -> tuple[str, ...]:
    """Each installed distribution's metadata folder, the first of each name, in sys.path's order."""
    seen: set[str] = set()
    folders = []
    for entry in sys.path:
        try:
            children = sorted(os.listdir(entry or "."))
        except OSError:
            continue
        for child in children:
            if child.lower().endswith(_INFO_SUFFIXES):
                name = normalized(child.rpartition(".")[0].partition("-")[0])
                if name not in seen:
                    seen.add(name)
                    folders.append(os.path.join(entry or ".", child))
    return tuple(folders)


def entry_points(group: str) -> Iterator[EntryPoint]:
    """Every installed distribution's entry points of `group`, in the distributions' order."""
    for folder in metadata_folders():
        yield from (point for point in _entry_points_of(folder) if point.group == group)


@functools.cache
def _entry_points_of(folder: str) -> tuple[EntryPoint, ...]:
    try:
        with open(os.path.join(folder, "entry_points.txt"), encoding="utf-8") as file:
            text = file.read()
    except (OSError, UnicodeDecodeError):
        return ()
    points, group = [], None
    for line in map(str.strip, text.splitlines()):
        if not line or line.startswith("#"):
            continue
        if line.startswith("[") and line.endswith("]"):
            group = line.strip("[]")
        elif group is not None and "=" in line:
            name, _, value = line.partition("=")
            points.append(EntryPoint(name.strip(), value.strip(), group))
    return tuple(points)


def version(distribution: str) -> str | None:
    """The `Version:` of an installed distribution's metadata (None: not installed, or unreadable)."""
    wanted = normalized(distribution)
    for folder in metadata_folders():
        if normalized(os.path.basename(folder).rpartition(".")[0].partition("-")[0]) != wanted:
            continue
        file_name = "METADATA" if folder.endswith(".dist-info") else "PKG-INFO"
        try:
            with open(os.path.join(folder, file_name), encoding="utf-8") as file:
                for line in file:
                    if line.startswith("Version:"):
                        return line.partition(":")[2].strip()
                    if not line.strip():  # the headers end at the first blank line
                        break
        except (OSError, UnicodeDecodeError):
            return None
        return None
    return None
