"""The CLI's two consoles, stdout and stderr: rich's, made on first use.

Importing rich and making its consoles is a large share of what `pbo run` does between parsing
its arguments and loading the file. Its start-up lines need none of it where rich would write
them as they are: on a stream that is not a terminal, with none of the variables that make rich
treat one as a terminal. There they are written straight to the stream, and rich is made for
the run's summary, once the configuration is on. On a terminal it is made at once, as before.
"""

from __future__ import annotations

import os
import sys
from typing import TYPE_CHECKING, Any, TextIO

if TYPE_CHECKING:
    from rich.console import Console

WIDTH_OFF_TERMINAL = 140  # logs and CI: wide enough for the summary, no wrapping
# what makes rich take a stream that is not a terminal for one (and style what it writes there)
RICH_TERMINAL_VARIABLES = ("FORCE_COLOR", "TTY_COMPATIBLE", "TTY_INTERACTIVE", "JUPYTER_COLUMNS", "JUPYTER_LINES")


def writes_plainly(stream: TextIO) -> bool:
    """Whether rich would write text to `stream` as it is: no terminal, nothing that makes rich think it is one."""
    if any(name in os.environ for name in RICH_TERMINAL_VARIABLES):
        return False
    try:
        return not stream.isatty()
    except (AttributeError, ValueError):  # a closed or odd stream: rich decides
        return False


class LazyConsole:
    """What the CLI's verbs print through: a rich `Console` (no highlighting, no emoji codes: the
    text is the user's), made the first time anything of it is used."""

    def __init__(self, stderr: bool = False, width_from: LazyConsole | None = None) -> None:
        self._stderr = stderr
        self._width_from = width_from  # the console whose terminal decides this one's width (stderr's: stdout's)
        self._console: Console | None = None

    @property
    def stream(self) -> TextIO:
        """Where it writes: the process's stdout or stderr now (as a rich console without a file does)."""
        return sys.stderr if self._stderr else sys.stdout

    @property
    def made(self) -> Console:
        """The rich console, made now if it was not (off a terminal: WIDTH_OFF_TERMINAL wide)."""
        if self._console is None:
            from rich.console import Console

            options: dict[str, Any] = {"stderr": self._stderr, "highlight": False, "emoji": False,
                                       "soft_wrap": self._stderr}
            console = Console(**options)
            terminal = console.is_terminal if self._width_from is None else self._width_from.is_terminal
            self._console = console if terminal else Console(**options, width=WIDTH_OFF_TERMINAL)
        return self._console

    @property
    def is_terminal(self) -> bool:
        return False if self._console is None and writes_plainly(self.stream) else self.made.is_terminal

    def write_plainly(self, line: str) -> bool:
        """Write `line` as it is, and a newline, if rich would have (it is not made yet, and this
        stream is no terminal); False if not written (print it through rich)."""
        if self._console is not None or not writes_plainly(self.stream):
            return False
        self.stream.write(line + "\n")
        self.stream.flush()  # (as rich flushes each print: a log is read as it is written)
        return True

    def __getattr__(self, name: str) -> Any:
        return getattr(self.made, name)


def rich_console(console: Console | LazyConsole) -> Console:
    """The rich console itself, for what rich is handed (a live view)."""
    return console.made if isinstance(console, LazyConsole) else console
