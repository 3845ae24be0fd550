"""The module library as data: every registered module with its ports and parameters.

`pbo lexicon` prints it (Onika's parameter file, read from the classes themselves: ports are
declared on the class, parameters are the fields of its `Params` dataclass), and the JSON schema
of the YAML format (`reports.schema`) takes the parameters from the same place.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import inspect
import io
import json
import re
import sys
import textwrap
import tokenize
import types
import typing
from typing import Any

from rich.markup import escape
from rich.table import Table

from pbo_runtime.objects import registry
from pbo_runtime.objects.module import PortBasedObject, param_ranges
from pbo_runtime.objects.ports import PortSpec
from pbo_runtime.objects.ranges import FINITE

PORTS_FROM_PARAMS = "ports depend on params (besides those listed)"


def lexicon() -> list[dict[str, Any]]:
    """One JSON-able entry per registered module, sorted by name.

    Each entry: name, summary (the class docstring's first line), ports (name, kind, variable,
    dtype, shape as text, doc), params (name, type, default, required, doc) and note (set when
    the ports depend on params, None otherwise). A module that fails to import gets an `error`.
    """
    entries: list[dict[str, Any]] = []
    for name in registry.names(registry.MODULES):
        try:
            cls = registry.module_class(name)
        except Exception as exc:  # a broken library is reported, not fatal to the listing
            entries.append({"name": name, "summary": "", "ports": [], "params": [], "note": None, "error": str(exc)})
            continue
        entries.append(module_entry(name, cls))
    return entries


def drivers() -> list[dict[str, Any]]:
    """One JSON-able entry per registered device driver (`pbo lexicon --drivers`), sorted by name.

    Each entry: name, class, kind (the report's three classes of driver, TR §4.6, read from what
    the class declares: `PORTS`, an I/O device; `download`, a special-purpose processor; else a
    sensor-actuator driver, wired through `IO` or not), device_kind (its `KIND`, what modules'
    `DEVICES` name), options (its `OPTIONS`, None when not declared), needs_plant, io (the I/O
    device kind a sensor is wired to, or ""), channels (an I/O device's) and summary. A driver
    that fails to import gets an `error`.
    """
    entries: list[dict[str, Any]] = []
    for name in registry.names(registry.DRIVERS):
        try:
            cls = registry.driver_class(name)
        except Exception as exc:  # a broken library is reported, not fatal to the listing
            entries.append({"name": name, "class": "", "kind": "", "device_kind": "", "options": None, "needs_plant": False,
                            "io": "", "channels": 0, "summary": "", "error": str(exc)})
            continue
        ports = int(getattr(cls, "PORTS", 0) or 0)
        kind = ("I/O device (TR 4.6.1)" if ports else
                "special-purpose processor (TR 4.6.3)" if callable(getattr(cls, "download", None)) else
                "sensor-actuator (TR 4.6.2)")
        declared = getattr(cls, "OPTIONS", None)
        entries.append({"name": name, "class": f"{cls.__module__}:{cls.__qualname__}", "kind": kind,
                        "device_kind": str(getattr(cls, "KIND", "") or ""),
                        "options": list(declared) if declared is not None else None,
                        "needs_plant": bool(getattr(cls, "NEEDS_PLANT", False)),
                        "io": str(getattr(cls, "IO", "") or ""), "channels": ports, "summary": first_line(cls.__doc__)})
    return entries


def drivers_table(entries: list[dict[str, Any]]) -> Table:
    """The device drivers as a rich Table: one row per driver."""
    table = Table(title="device drivers (entry points 'pbo.drivers')", title_justify="left")
    for column in ("driver", "kind", "wired to", "options", "summary"):
        table.add_column(column)
    for entry in entries:
        wired = f"{entry['io']} channels" if entry["io"] else (f"{entry['channels']} channels" if entry["channels"] else "")
        summary = entry.get("error") or entry["summary"]
        options = "any" if entry["options"] is None else ", ".join(entry["options"]) or "none"
        kind = f"{entry['device_kind']}: {entry['kind']}" if entry["device_kind"] else entry["kind"]
        table.add_row(escape(entry["name"]), escape(kind), wired, escape(options), escape(summary))
    return table


def module_entry(name: str, cls: type[PortBasedObject]) -> dict[str, Any]:
    """The lexicon entry of one module class."""
    return {
        "name": name,
        "class": f"{cls.__module__}:{cls.__qualname__}",
        "summary": first_line(cls.__doc__),
        "ports": [port_entry(p) for p in cls.ports()],
        "params": params_info(getattr(cls, "Params", None)),
        "note": _ports_note(cls),
    }


def port_entry(port: PortSpec) -> dict[str, Any]:
    return {
        "name": port.name,
        "kind": port.kind.value,
        "variable": port.variable,
        "dtype": port.dtype,
        "shape": shape_text(port.shape),
        "doc": port.doc,
    }


def shape_text(shape: tuple[int | str, ...] | None) -> str:
    """`[NDOF, 4]`, `[]` for a scalar, `as variable` for a port that takes its variable's shape."""
    if shape is None:
        return "as variable"
    return "[" + ", ".join(str(d) for d in shape) + "]"


def first_line(doc: str | None) -> str:
    """The docstring's first line, or its first sentence where that sentence runs on past the line."""
    text = inspect.cleandoc(doc or "")
    if not text:
        return ""
    paragraph = " ".join(line.strip() for line in text.split("\n\n")[0].splitlines())
    line = text.splitlines()[0].strip()
    if line.endswith((".", ":", "!", "?")) or paragraph == line:
        return line
    sentence = re.split(r"(?<=[.!?])\s", paragraph, maxsplit=1)[0]
    return sentence if sentence.endswith((".", "!", "?")) else line


def ports_depend_on_params(cls: type) -> bool:
    """True when the class overrides `ports_for` (e.g. a data logger's one input per logged variable)."""
    own = getattr(cls, "ports_for", None)
    base = PortBasedObject.ports_for
    return getattr(own, "__func__", own) is not getattr(base, "__func__", base)


def _ports_note(cls: type[PortBasedObject]) -> str | None:
    """For a module whose ports depend on params: the note, with the sentence of its docs that says how."""
    if not ports_depend_on_params(cls):
        return None
    docs = [getattr(cls.ports_for, "__doc__", None), cls.__doc__, getattr(sys.modules.get(cls.__module__), "__doc__", None)]
    if docs[0] == PortBasedObject.ports_for.__doc__:
        docs = docs[1:]
    for doc in docs:
        text = " ".join(inspect.cleandoc(doc or "").split())
        for sentence in re.split(r"(?<=[.;])\s", text):
            if "params." in sentence:
                sentence = sentence.rstrip(".;")
                return f"{PORTS_FROM_PARAMS}: {sentence[:1].lower()}{sentence[1:]}"
    return PORTS_FROM_PARAMS


# --- parameters -------------------------------------------------------------------------------


def params_info(params_type: type | None) -> list[dict[str, Any]]:
    """The fields of a module's `Params` dataclass: name, type (text), default, required, doc, range.

    The range is the field's declared one in words ('in [0, 1e+06]'; `objects.ranges.param`), or
    'a finite number' for a number parameter that declares none, else empty.

    The doc is the field's `metadata['doc']`, else the comment at the end of its line in the
    source (`kp: Gain = 400.0  # N m / rad`), else empty.
    """
    if params_type is None or not dataclasses.is_dataclass(params_type):
        return []
    try:
        hints = typing.get_type_hints(params_type)
    except Exception:  # unresolvable annotations: fall back to the raw ones
        hints = {}
    comments = field_comments(params_type)
    ranges = param_ranges(params_type)
    out = []
    for f in dataclasses.fields(params_type):
        hint = hints.get(f.name, f.type)
        required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            default = None
        out.append(
            {
                "name": f.name,
                "type": type_text(hint),
                "default": jsonable(default),
                "required": required,
                "doc": str(f.metadata.get("doc", "")) or comments.get(f.name, ""),
                "range": ranges[f.name].text() if f.name in ranges else FINITE.text() if _takes_numbers(hint) else "",
            }
        )
    return out


def _takes_numbers(hint: Any) -> bool:
    """Whether a field of this type takes floats (a number, a list of them), which are finite at least."""
    if hint is float:
        return True
    return any(_takes_numbers(arg) for arg in typing.get_args(hint) if arg is not Ellipsis)


def param_hints(params_type: type | None) -> dict[str, Any]:
    """Field name -> resolved type hint of a `Params` dataclass (empty if it is not one)."""
    if params_type is None or not dataclasses.is_dataclass(params_type):
        return {}
    try:
        hints = typing.get_type_hints(params_type)
    except Exception:
        hints = {}
    return {f.name: hints.get(f.name, f.type) for f in dataclasses.fields(params_type)}


@functools.cache
def field_comments(cls: type) -> dict[str, str]:
    """Field name -> the comment that ends its line in the class's source; {} if no source."""
    try:
        source = textwrap.dedent(inspect.getsource(cls))
        tree = ast.parse(source)
    except (OSError, TypeError, SyntaxError):
        return {}
    comments: dict[int, str] = {}
    try:
        for token in tokenize.generate_tokens(io.StringIO(source).readline):
            if token.type == tokenize.COMMENT:
                comments[token.start[0]] = token.string.lstrip("#").strip()
    except (tokenize.TokenError, IndentationError):
        return {}
    node = tree.body[0] if tree.body else None
    if not isinstance(node, ast.ClassDef):
        return {}
    found = {}
    for stmt in node.body:
        if isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name):
            line = stmt.end_lineno or stmt.lineno
            if line in comments:
                found[stmt.target.id] = comments[line]
    return found


def type_text(hint: Any) -> str:
    """A type hint as a reader writes it: `float`, `tuple[str, ...]`, `float | tuple[float, ...]`."""
    if hint is type(None):
        return "None"
    if isinstance(hint, type) and not typing.get_args(hint):
        return hint.__name__
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return " | ".join(type_text(a) for a in args)
    if origin is typing.Literal:  # the values a YAML file may give: `"raise" | "hang"`
        return " | ".join(json.dumps(a) for a in args)
    if origin is not None and args:
        name = getattr(origin, "__name__", str(origin))
        return f"{name}[{', '.join('...' if a is Ellipsis else type_text(a) for a in args)}]"
    if hint is typing.Any:
        return "Any"
    return str(hint).replace("typing.", "")


def jsonable(value: Any) -> Any:
    """A default value as JSON: tuples become lists; anything exotic becomes its repr."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, (tuple, list)):
        return [jsonable(v) for v in value]
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    return repr(value)


# --- the table --------------------------------------------------------------------------------


def as_table(entries: list[dict[str, Any]]) -> Table:
    """The lexicon as a rich Table: one row per module, its ports and its params side by side."""
    table = Table(title="module library (entry points 'pbo.modules')", title_justify="left", show_lines=True)
    table.add_column("module", max_width=30)
    table.add_column("ports: name, kind, variable, dtype, shape")
    table.add_column("params: name, type, range, default")
    for entry in entries:
        about = [f"[bold]{escape(entry['name'])}[/bold]"]
        for text, style in ((entry.get("summary"), "dim"), (entry.get("note"), "italic"), (entry.get("error"), "red")):
            if text:
                about.append(f"[{style}]{escape(text)}[/{style}]")
        ports = Table.grid(padding=(0, 1))
        for _ in range(5):
            ports.add_column(no_wrap=True)
        for p in entry.get("ports", []):
            ports.add_row(escape(p["name"]), p["kind"], escape(p["variable"]), p["dtype"], escape(p["shape"]))
        if not entry.get("ports"):
            ports.add_row("[dim](none declared)[/dim]", "", "", "", "")
        params = Table.grid(padding=(0, 1))
        params.add_column(no_wrap=True)
        params.add_column(no_wrap=True)
        params.add_column()
        for q in entry.get("params", []):
            default = "[yellow]required[/yellow]" if q["required"] else escape(_show_default(q["default"]))
            doc = f"[dim]{escape(q['doc'])}[/dim]" if q.get("doc") else ""
            allowed = f" [cyan]{escape(q['range'])}[/cyan]" if q.get("range") else ""
            params.add_row(f"{escape(q['name'])}: {escape(q['type'])}{allowed}", default, doc)
        if not entry.get("params"):
            params.add_row("[dim](none)[/dim]", "", "")
        table.add_row("\n".join(about), ports, params)
    return table


def _show_default(value: Any) -> str:
    if isinstance(value, list):
        return "[" + ", ".join(_show_default(v) for v in value) + "]"
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "null"
    return str(value) if not isinstance(value, str) else repr(value)
