"""Arrays computed once per machine and kept on disk, so a later process reads them instead of
importing what computed them (`pbo check` of a file with a joint loop reads its arm's inertia
range without Pinocchio).

An entry is named by a hash of everything its value depends on: the caller's inputs, and the
source files and installed libraries that compute it, so a changed input, a changed computation
or another library version reads as a miss, never as a stale value. The folder is `cache_folder`'s
(PBO_CACHE_DIR=off keeps nothing). A folder that cannot be read or written costs the computation, never the answer.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from pbo_runtime.objects.cache_folder import cache_folder, keep_whole

FORMAT = 1  # what an entry holds and how: a change here names every entry anew


def cache_dir() -> Path | None:
    """Where entries are kept (None: PBO_CACHE_DIR=off)."""
    folder = cache_folder()
    return Path(folder) if folder is not None else None


def fingerprint(*parts: bytes | str, sources: tuple[str, ...] = (), libraries: tuple[str, ...] = ()) -> str:
    """The entry's name: a hash of `parts`, of the `sources` files' bytes, and of where each of the
    `libraries` is installed and when (found without importing it)."""
    digest = hashlib.sha256(f"format {FORMAT}".encode())
    for part in parts:
        digest.update(part.encode() if isinstance(part, str) else part)
        digest.update(b"\0")
    for source in sources:
        digest.update(Path(source).read_bytes())
    for library in libraries:
        spec = importlib.util.find_spec(library)
        origin = spec.origin if spec is not None and spec.origin else ""
        digest.update(f"{library} {origin} {os.stat(origin).st_mtime_ns if origin else ''}".encode())
    return digest.hexdigest()


def cached_arrays(name: str, compute: Callable[[], dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The arrays (numbers or text, no objects) kept under `name`, else `compute()`'s, kept for the next process."""
    folder = cache_dir()
    path = folder / f"{name}.npz" if folder is not None else None
    if path is not None:
        try:
            with np.load(path, allow_pickle=False) as kept:
                return {key: kept[key] for key in kept.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile):  # not there yet, or unreadable: computed again
            pass
    value = compute()
    if path is not None:  # written whole or not at all; a read-only home: the next process computes it again
        keep_whole(str(path), lambda file: np.savez(file, **value))  # type: ignore[arg-type]  # (the stubs read a name as savez's allow_pickle)
    return value
