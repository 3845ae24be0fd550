"""The one tree a load may read from: what keeps the local API inside the subsystem's own folder.

`pbo check` follows an `include:` (and a plant's robot file) wherever it points: the user reads
their own files. The API (`pbo hmi`) must not: a YAML text posted to it, or a canvas, could
otherwise name `/etc/shadow` and have its first line echoed in an error. Within `confined(root)`,
the loader and the checker refuse, before opening it, any file whose real path (symlinks
followed) leaves `root`: E107, which names the path as written and never its content.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar

OUTSIDE_ROOT = "E107"  # the code of a file refused for leaving the root
_ROOT: ContextVar[str | None] = ContextVar("pbo_config_root", default=None)


@contextmanager
def confined(root: str | os.PathLike[str] | None) -> Iterator[None]:
    """Within it, loads and checks read no file outside `root`'s tree; None lifts the confinement."""
    token = _ROOT.set(os.path.realpath(root) if root is not None else None)
    try:
        yield
    finally:
        _ROOT.reset(token)


def current_root() -> str | None:
    """The tree loads are confined to now (a real path), or None (pbo check's rules: any file)."""
    return _ROOT.get()


def is_within(path: str | os.PathLike[str], root: str) -> bool:
    """Whether `path`'s real path (symlinks followed) is `root` or under it; `root` a real path."""
    try:
        real = os.path.realpath(path)
    except (OSError, ValueError):  # a NUL character, a loop of links
        return False
    return real == root or real.startswith(root.rstrip(os.sep) + os.sep)


def leaves_root(path: str | os.PathLike[str]) -> str | None:
    """The root `path` leaves, or None when it stays in it or no root is in force."""
    root = _ROOT.get()
    return None if root is None or is_within(path, root) else root
