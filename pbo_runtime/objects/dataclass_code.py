"""Dataclass methods compiled once per machine, as .pyc files keep a module's bytecode.

`dataclasses` writes each method it makes (__init__, __eq__, __repr__, ...) as source text and
compiles it, in every process, for every class: a large part of importing the runtime's models and
messages. `dataclasses` calls `exec` by name, found in its module before builtins:
`install()` gives it one that runs the code kept for that very text and compiles only a text not
seen before; `save()` keeps the new ones for the next process. Nothing else about the class changes.
An entry stays marshalled until its text is run: a process pays only for the classes it makes.

The file is in the cache folder (`cache_folder`), one per interpreter build. It is trusted as a
user's own bytecode is: read only if it is a regular file of this user that no one else may write,
and only if it was written by this very interpreter (`sys.version` heads it); anything else,
missing, corrupt or truncated reads as empty, never as an error; an entry that is not code is
compiled again. Only os (and its stat), sys, marshal and builtins are imported here: the CLI
installs it before its own imports.
"""

from __future__ import annotations  # (the code compiled here does not inherit it: dont_inherit)

import builtins
import marshal
import os
import stat  # (imported by os already)
import sys

TYPE_CHECKING = False  # typing's, without importing typing
if TYPE_CHECKING:
    from typing import Any

LIMIT = 4096  # entries the file holds at most: over it, a process keeps only the ones it used
HEADER = f"pbo dataclass code 1\0{sys.version}\0".encode()

_kept: dict[str, bytes] = {}  # source text -> its marshalled code object, as the file held it
_code: dict[str, Any] = {}  # source text -> its code object, made in this process (or before its fork)
_new: dict[str, Any] = {}  # those compiled in this process and not yet saved
_used: set[str] = set()  # texts this process ran
_path: str | None = None  # the file (None: not installed)
compiled = 0  # methods this process compiled (a forked one: since its fork)


def install() -> bool:
    """Run each dataclass method from its kept code, compiling only new texts (True: installed by
    this call; False: installed already, or PBO_CACHE_DIR=off)."""
    global _path
    if _path is not None:
        return False
    from pbo_runtime.objects.cache_folder import cache_folder

    folder = cache_folder()
    if folder is None:
        return False
    import dataclasses

    _path = os.path.join(folder, f"dataclass-code.{sys.implementation.cache_tag}.marshal")
    _kept.update(read(_path))
    dataclasses.exec = _exec  # type: ignore[attr-defined]
    os.register_at_fork(after_in_child=_forked)
    return True


def _forked() -> None:
    """In a forked child: what the parent compiled is the parent's to save."""
    global compiled
    _new.clear()
    compiled = 0


def save() -> None:
    """Add this process's new code to the file, merged with what the file holds now (no-op if none)."""
    if not _new or _path is None:
        return
    from pbo_runtime.objects.cache_folder import keep_whole

    mine = {text: marshal.dumps(code) for text, code in list(_new.items())}  # (a thread may add one meanwhile)
    merged = read(_path)
    merged.update(mine)
    if len(merged) > LIMIT:
        merged = {text: data for text, data in merged.items() if text in _used}
    if not keep_whole(_path, lambda file: file.write(HEADER + marshal.dumps(merged))):
        return  # a read-only home: the next process compiles them again
    for text in mine:
        del _new[text]


def read(path: str) -> dict[str, bytes]:
    """The entries kept in `path`: empty unless the file is trusted, whole, and of this interpreter."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError:
        return {}
    try:
        status = os.fstat(fd)
        if not stat.S_ISREG(status.st_mode) or status.st_uid != os.geteuid() or status.st_mode & 0o022:
            return {}
        chunks = []
        while chunk := os.read(fd, max(status.st_size, 1 << 16)):
            chunks.append(chunk)
        data = b"".join(chunks)
        if not data.startswith(HEADER):
            return {}
        kept = marshal.loads(memoryview(data)[len(HEADER):])
    except (OSError, ValueError, EOFError, TypeError):
        return {}
    finally:
        os.close(fd)
    if type(kept) is not dict or not all(type(text) is str and type(code) is bytes for text, code in kept.items()):
        return {}
    return kept


def _code_for(source: str) -> Any:
    """The code object of `source`: compiled here before, kept, or compiled now."""
    global compiled
    _used.add(source)
    code = _code.get(source)
    if code is not None:
        return code
    data = _kept.get(source)
    if data is not None:
        try:
            code = marshal.loads(data)
        except (ValueError, EOFError, TypeError):
            code = None
    if type(code) is not type(_code_for.__code__):
        code = _new[source] = compile(source, "<string>", "exec", dont_inherit=True)
        compiled += 1
    _code[source] = code
    return code


def _exec(source: Any, globals: Any = None, locals: Any = None, /, *args: Any, **kwargs: Any) -> None:
    """`dataclasses`'s exec: a method's text runs from its kept code object."""
    if type(source) is str and type(globals) is dict:
        source = _code_for(source)
    return builtins.exec(source, globals, locals, *args, **kwargs)
