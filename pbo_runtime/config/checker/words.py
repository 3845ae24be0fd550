"""How the checker words what it found: hints for unknown names, short descriptions of values,
times, shapes and lists as a message shows them.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from pbo_runtime.config.values import describe as describe  # the same words for values wherever they are checked
from pbo_runtime.errors import closest_name

LISTED = 12  # choices named in a hint; a longer list helps nobody read it


def did_you_mean(name: object, choices: Iterable[str], what: str = "valid") -> str:
    """'did you mean 'x'? (valid: a, b, c)' - the hint for an unknown name."""
    options = sorted({str(c) for c in choices})
    close = closest_name(name, options)
    shown = options if len(options) <= LISTED else [*options[:LISTED], f"... {len(options) - LISTED} more"]
    listing = f"({what}: {', '.join(shown)})" if options else f"({what}: none)"
    if close:
        return f"did you mean '{close}'? {listing}"
    return listing


def _ms(seconds: float) -> str:
    """A time as an engineer writes it: '1 ms', '0.25 ms', '2 s'."""
    if seconds >= 1:
        return f"{seconds:g} s"
    return f"{seconds * 1e3:g} ms"


def _show_shape(shape: Sequence[object] | None) -> str:
    if not shape:
        return "() (a scalar)"
    return "(" + ", ".join(str(d) for d in shape) + ("," if len(shape) == 1 else "") + ")"


def _and_list(items: Sequence[str]) -> str:
    """'a', 'a and b', 'a, b and c'."""
    if len(items) <= 1:
        return "".join(items)
    return ", ".join(items[:-1]) + " and " + items[-1]
