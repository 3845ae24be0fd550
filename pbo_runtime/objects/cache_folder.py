"""Where pbo keeps what a machine computes once (`result_cache`, `dataclass_code`).

$PBO_CACHE_DIR, else $XDG_CACHE_HOME/pbo-runtime, else ~/.cache/pbo-runtime; PBO_CACHE_DIR=off
keeps nothing. Only `os`: the CLI asks before its own imports.
"""

import os


def cache_folder() -> str | None:
    """The folder's path (None: PBO_CACHE_DIR=off)."""
    chosen = os.environ.get("PBO_CACHE_DIR", "")
    if chosen == "off":
        return None
    if chosen:
        return chosen
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "pbo-runtime")
