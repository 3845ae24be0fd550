"""Where `pbo run` writes its results: checked before anything starts, written so a failure loses nothing.

`--out DIR` and `--report FILE` are tried before the run starts (`check_output_dir`,
`check_report_path`): a path under /proc or /sys, a directory that cannot be made, a file
system that is read-only or full, a device that refuses writes (/dev/full) is refused with one
line and a hint, and the run never starts. What can still fail at the end (the disk filled during
the run) is written by `write_report`: a regular file through a temporary file in the same
directory and `os.replace`, so the path holds either the previous report or the whole new one,
never a truncated one; a device or pipe (`/dev/stdout`) is written in place.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import tempfile
from pathlib import Path

from pbo_runtime.errors import PboError

PSEUDO_FILE_SYSTEMS = (Path("/proc"), Path("/sys"))  # files there are kernel knobs, never a run's results
PROBE = b"{}\n"  # a few bytes: a full file system refuses even these (a page to allocate)


class OutputPathError(PboError):
    """An output path that cannot take the run's results: the message names it, the OS error and the fix."""


def check_output_dir(directory: Path, option: str = "--out") -> None:
    """Make `directory` if needed and prove a file can be written there; OutputPathError if not."""
    _refuse_pseudo(directory, option)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputPathError(f"{option} {directory}: exists and is not a directory; name a directory "
                              "(it is made if missing)") from None
    except OSError as exc:
        raise OutputPathError(f"{option} {directory}: cannot make the directory: {_os_error(exc)}; "
                              f"{_hint(exc)}") from None
    _probe_directory(directory, option, directory)


def check_report_path(path: Path, option: str = "--report") -> None:
    """Prove the report can be written at `path` (its directory made if needed); OutputPathError if not.

    An existing regular file is left as it is until the new report replaces it whole.
    """
    _refuse_pseudo(path, option)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        mode = None
    except OSError as exc:
        raise OutputPathError(f"{option} {path}: {_os_error(exc)}; {_hint(exc)}") from None
    if mode is not None and stat.S_ISDIR(mode):
        raise OutputPathError(f"{option} {path}: is a directory; name a file (or use --out DIR for DIR/report.json)")
    if mode is not None and not stat.S_ISREG(mode):
        _probe_in_place(path, option)
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputPathError(f"{option} {path}: cannot make its directory {path.parent}: {_os_error(exc)}; "
                              f"{_hint(exc)}") from None
    _probe_directory(path.parent, option, path)


def write_report(path: Path, text: str) -> None:
    """Write `text` to `path` whole or not at all; OutputPathError naming the path and the OS error."""
    data = text.encode()
    try:
        mode = path.stat().st_mode
    except OSError:
        mode = None
    try:
        if mode is not None and not stat.S_ISREG(mode) and not stat.S_ISDIR(mode):
            with open(path, "ab", buffering=0) as device:  # /dev/stdout, a pipe: no file to replace
                device.write(data)
            return
        _replace_atomically(path, data)
    except OSError as exc:
        raise OutputPathError(f"cannot write the run report {path}: {_os_error(exc)}; {_hint(exc)}") from None


def _replace_atomically(path: Path, data: bytes) -> None:
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(handle, "wb") as file:
            file.write(data)
            file.flush()
            os.fsync(file.fileno())  # the data is on disk before the name points at it
        os.chmod(temporary, 0o644)  # mkstemp's 0600 would make a report the operator's group cannot read
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise


def _probe_directory(directory: Path, option: str, named: Path) -> None:
    """Write and flush a few bytes to a temporary file in `directory`, then remove it."""
    try:
        handle, temporary = tempfile.mkstemp(dir=directory, prefix=".pbo-probe-")
    except OSError as exc:
        raise OutputPathError(f"{option} {named}: cannot create a file in {directory}: {_os_error(exc)}; "
                              f"{_hint(exc)}") from None
    try:
        with os.fdopen(handle, "wb") as file:
            file.write(PROBE)
            file.flush()
            os.fsync(file.fileno())
    except OSError as exc:
        raise OutputPathError(f"{option} {named}: cannot write in {directory}: {_os_error(exc)}; "
                              f"{_hint(exc)}") from None
    finally:
        with contextlib.suppress(OSError):
            os.unlink(temporary)


def _probe_in_place(path: Path, option: str) -> None:
    """An existing device or pipe: open it for append and write nothing (/dev/full refuses even that)."""
    try:
        handle = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_NONBLOCK)
    except OSError as exc:
        if exc.errno == errno.ENXIO:
            raise OutputPathError(f"{option} {path}: is a pipe with no reader; start its reader first, or name a file") from None
        raise OutputPathError(f"{option} {path}: cannot open it for writing: {_os_error(exc)}; {_hint(exc)}") from None
    try:
        os.write(handle, b"")
    except BlockingIOError:
        pass  # a pipe that is full now: it drains while the run goes
    except OSError as exc:
        raise OutputPathError(f"{option} {path}: refuses writes: {_os_error(exc)}; name a file on a disk") from None
    finally:
        os.close(handle)


def _refuse_pseudo(path: Path, option: str) -> None:
    absolute = Path(os.path.abspath(path))  # not resolved: /dev/stdout is a link into /proc, and a fine report path
    for pseudo in PSEUDO_FILE_SYSTEMS:
        if absolute == pseudo or pseudo in absolute.parents:
            raise OutputPathError(f"{option} {path}: is under {pseudo}, the kernel's own files, not a place for "
                                  "a run's results; name a directory on a disk, e.g. runs/")


def _os_error(exc: OSError) -> str:
    return f"[Errno {exc.errno}] {exc.strerror}" if exc.errno is not None and exc.strerror else str(exc)


def _hint(exc: OSError) -> str:
    """What usually fixes the OS error `exc`, as the tail of a one-line message."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return "free space on that file system (df -h shows it) or name another place"
    if exc.errno == errno.EROFS:
        return "the file system is read-only: name a place on a writable one"
    if exc.errno in (errno.EACCES, errno.EPERM):
        return "you may not write there: name a place you own"
    if exc.errno == errno.ENOTDIR:
        return "a part of the path is a file, not a directory"
    if exc.errno in (errno.EMFILE, errno.ENFILE):
        return "too many files are open: raise the limit (ulimit -n 4096) or close other programs"
    return "name another place"
