"""Exception types, each saying which object and which rule (STYLE.md §9)."""

from __future__ import annotations


class PboError(Exception):
    """Base of every error this runtime raises on purpose."""


class ConfigError(PboError):
    """A mistake in a YAML file; carries where it is and a hint.

    `severity` is "error" (the file is refused) or "warning" (it runs, but probably not as meant).
    A line of 0 means the problem belongs to the whole file (e.g. it cannot be read).
    """

    def __init__(
        self,
        message: str,
        file: str = "",
        line: int = 0,
        column: int = 0,
        hint: str = "",
        severity: str = "error",
    ) -> None:
        if severity not in ("error", "warning"):
            raise ValueError(f"severity must be 'error' or 'warning', got: {severity!r}")
        self.message = message
        self.file = file
        self.line = line
        self.column = column
        self.hint = hint
        self.severity = severity
        super().__init__(self.format())

    def format(self) -> str:
        if self.file and self.line:
            where = f"{self.file}:{self.line}:{self.column}: "
        elif self.file:
            where = f"{self.file}: "
        else:
            where = ""
        text = f"{where}{self.severity}: {self.message}"
        if self.hint:
            text += f"\n  hint: {self.hint}"
        return text


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


class InternalError(PboError):
    """An invariant of the runtime itself broke: please report this with the command you ran."""
