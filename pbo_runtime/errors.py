"""Exception types, each saying which object and which rule (STYLE.md §9)."""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from typing import NamedTuple


class Note(NamedTuple):
    """A place related to a diagnostic, as a compiler's note: the diagnostic itself points where the
    fix goes, a note where else the problem shows (the ports that read a mistyped variable)."""

    message: str
    file: str = ""
    line: int = 0
    column: int = 0

    def format(self) -> str:
        return f"{_where(self.file, self.line, self.column)}note: {self.message}"


def _where(file: str, line: int, column: int) -> str:
    if file and line:
        return f"{file}:{line}:{column}: "
    if file:
        return f"{file}: "
    return ""


class PboError(Exception):
    """Base of every error this runtime raises on purpose."""


class ConfigError(PboError):
    """A mistake in a YAML file; carries where it is, a stable code and a hint.

    `severity` is "error" (the file is refused) or "warning" (it runs, but probably not as meant).
    `code` names the rule ("E101", "W201"; docs/error-codes.md lists them all). A diagnostic made
    without one (the YAML reader's, the include loader's) gets it from its message's first words.
    A line of 0 means the problem belongs to the whole file (e.g. it cannot be read). Its location
    is where the fix goes; `notes` are the related places, each printed on a line of its own.
    """

    def __init__(
        self,
        message: str,
        file: str = "",
        line: int = 0,
        column: int = 0,
        hint: str = "",
        severity: str = "error",
        code: str = "",
        notes: Sequence[Note] = (),
    ) -> None:
        if severity not in ("error", "warning"):
            raise ValueError(f"severity must be 'error' or 'warning', got: {severity!r}")
        if code and not _CODE.match(code):
            raise ValueError(f"code must look like 'E101' or 'W201', got: {code!r}")
        self.message = message
        self.file = file
        self.line = line
        self.column = column
        self.hint = hint
        self.severity = severity
        self.code = code or infer_code(message)
        self.notes = tuple(notes)
        super().__init__(self.format())

    def format(self) -> str:
        tag = f"{self.severity}[{self.code}]" if self.code else self.severity
        text = f"{_where(self.file, self.line, self.column)}{tag}: {self.message}"
        for note in self.notes:
            text += f"\n  {note.format()}"
        if self.hint:
            text += f"\n  hint: {self.hint}"
        return text


_CODE = re.compile(r"^[EW]\d{3}$")

# Codes of the diagnostics made outside the checker (`config.yaml_nodes`, `config.loader`), which
# build ConfigError from a message alone: the first pattern that matches the message wins.
_INFERRED: tuple[tuple[re.Pattern[str], str], ...] = tuple(
    (re.compile(pattern), code)
    for pattern, code in (
        (r"^(cannot read file|is a directory|not UTF-8 text|invalid character U\+)", "E100"),
        (r"^the file is [\d,]+ bytes.*; a configuration file may be at most", "E106"),
        (r"^duplicate key ", "E102"),
        (r"^(YAML tag |a key must be a plain name|a merge key)", "E103"),
        (r"^(YAML expands to more than|an alias refers to a node that contains it)", "E104"),
        (r"^(invalid YAML|YAML is nested too deeply|unexpected YAML node|cannot read value )", "E101"),
        (r"^('include' must be|an include must be|included file |'[^']*' includes itself)", "E105"),
        (r"^'[^']*' (in '[^']*' is defined twice|is given twice)", "E215"),
        (r"^internal error", "E901"),
    )
)


def infer_code(message: str) -> str:
    """The code of a message made without one, or "" when no rule claims it."""
    for pattern, code in _INFERRED:
        if pattern.match(message):
            return code
    return ""


class ConfigErrors(PboError):
    """Every error found in one pass over the files."""

    def __init__(self, errors: list[ConfigError]) -> None:
        self.errors = list(errors)
        super().__init__("\n".join(e.format() for e in self.errors))


class ParamError(PboError):
    """A module's parameters do not fit its `Params` declaration."""


class ModuleError(PboError):
    """A module could not be found, or broke its contract."""


class TableLayoutError(PboError):
    """The shared table's layout differs from what this process expects."""


class LifecycleError(PboError):
    """A signal that is not legal in the task's current state (e.g. `on` while ERROR)."""


class OutputError(PboError):
    """A file the run promised (a data log) could not be written: the message names it and the OS error.

    Raised from a module's component, it puts the task in ERROR like any exception, and the
    run's exit status then says a fault happened (`pbo run` exits 2), though the run goes on.
    """


class ResourceLimitError(PboError):
    """An OS limit stopped the run (queue memory, open files, /dev/shm space): one line naming the
    limit, its value, what the run needs, and how to raise it."""


class InternalError(PboError):
    """An invariant of the runtime itself broke: please report this with the command you ran."""


def closest_name(name: object, choices: Iterable[str]) -> str | None:
    """The one of `choices` an unknown `name` most likely meant, or None: a truncation first
    ('prio' for 'priority', which difflib alone may take for 'period'), then the closest spelling."""
    import difflib

    text, options = str(name), sorted({str(c) for c in choices})
    truncated = [o for o in options if len(text) >= 3 and o.startswith(text)]
    if truncated:
        return truncated[0]
    close = difflib.get_close_matches(text, options, n=1, cutoff=0.6)
    return close[0] if close else None


class MissingExtra(PboError):
    """A verb needs a part of pbo-runtime the install left out (an optional extra)."""


EXTRAS = {"fastapi": "hmi", "uvicorn": "hmi", "websockets": "hmi", "matplotlib": "plot", "zenoh": "links",
          "cyclonedds": "ros2", "rosbags": "ros2"}


def require_extra(module: str, what: str) -> None:
    """Import `module` or raise MissingExtra: "`what` needs the 'hmi' extra (...): pip install ..."."""
    import importlib

    try:
        importlib.import_module(module)
    except ImportError:
        extra = EXTRAS[module]
        raise MissingExtra(f"{what} needs the '{extra}' extra ({module} is not installed): "
                           f"pip install 'pbo-runtime[{extra}]'") from None
