"""Where pbo keeps what a machine computes once (`result_cache`, `dataclass_code`), and how a file
of it is written.

$PBO_CACHE_DIR, else $XDG_CACHE_HOME/pbo-runtime, else ~/.cache/pbo-runtime; PBO_CACHE_DIR=off
keeps nothing. Only `os`: the CLI asks before its own imports.
"""

from __future__ import annotations

import os

TYPE_CHECKING = False  # typing's, without importing typing
if TYPE_CHECKING:
    from collections.abc import Callable
    from typing import BinaryIO


def cache_folder() -> str | None:
    """The folder's path (None: PBO_CACHE_DIR=off)."""
    chosen = os.environ.get("PBO_CACHE_DIR", "")
    if chosen == "off":
        return None
    if chosen:
        return chosen
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "pbo-runtime")


def keep_whole(path: str, write: Callable[[BinaryIO], object]) -> bool:
    """Write the file `path` whole or not at all: `write` fills a temporary file beside it (0600),
    which is then renamed over it. False if its folder cannot take it (a read-only home: the next
    process computes it again)."""
    import tempfile

    folder = os.path.dirname(path)
    try:
        os.makedirs(folder, exist_ok=True)
        fd, temporary = tempfile.mkstemp(dir=folder, prefix=f".{os.path.basename(path)}.", suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as file:
                write(file)
            os.replace(temporary, path)
        except BaseException:
            os.unlink(temporary)
            raise
    except OSError:
        return False
    return True
