"""Shell completion: the verbs and flags (shtab, from the parser), and the names a file or a live run has.

`pbo completion bash` prints the script. A name (a task, a configuration, a job, an application,
a variable, a device, a running subsystem or run) is completed at the time of the <TAB> by
`pbo __complete KIND WORD...`: the shell passes the command line's words; the names come from the
subsystem file among them (`pbo run FILE --config <TAB>`), else from the one live run (`pbo off
<TAB>`: its tasks as it runs them, spawned ones included, and its file's other names).
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from rich.console import Console

HIDDEN_VERB = "__complete"  # not a verb of the parser: main() answers it before parsing
SECTIONS = {"configuration": "configurations", "job": "jobs", "application": "applications", "variable": "variables",
            "device": "devices"}
LIVE_PATIENCE = 0.5  # s the live run's status may take before completion makes do with its file


def print_script(args: argparse.Namespace, console: Console, errors: Console) -> int:
    """`pbo completion SHELL`."""
    from pbo_runtime.cli.parser import build_parser

    console.out(script(build_parser(), args.shell), end="")
    return 0


def script(parser: argparse.ArgumentParser, shell: str) -> str:
    """The completion script for `shell`, with the names completed at the time of the <TAB>."""
    import shtab

    _attach(parser)
    return shtab.complete(parser, shell=shell)


def _attach(parser: argparse.ArgumentParser) -> None:
    """Each argument the verb tables say completes a kind of name (`cli.parser` marks it): how each shell asks for them."""
    for action in parser._actions:
        kind = getattr(action, "complete_kind", None)
        if kind is not None:
            action.complete = _names(kind)  # type: ignore[attr-defined]
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                _attach(sub)


def _names(kind: str) -> dict[str, Any]:
    """shtab's custom completion: each shell asks `pbo __complete KIND` with its command line's words."""
    function = f"_pbo_complete_{kind}"
    return {
        "bash": function,
        "zsh": f'(${{(f)"$(pbo {HIDDEN_VERB} {kind} ${{words[@]}} 2>/dev/null)"}})',
        "tcsh": f"`pbo {HIDDEN_VERB} {kind} $COMMAND_LINE`",
        "preamble": {
            "bash": f'{function}() {{ compgen -W "$(pbo {HIDDEN_VERB} {kind} "${{COMP_WORDS[@]}}" 2>/dev/null)" -- "$1"; }}'
        },
    }


def complete(arguments: list[str]) -> int:
    """`pbo __complete KIND WORD...`: the names of KIND, one a line; nothing (never an error) if none."""
    if not arguments:
        return 0
    kind, words = arguments[0], arguments[1:]
    for name in names(kind, words):
        print(name)
    return 0


def names(kind: str, words: Iterable[str]) -> list[str]:
    words = list(words)
    try:
        if kind in ("subsystem", "run"):
            from pbo_runtime.ipc.runs import live_runs

            return sorted({run.subsystem if kind == "subsystem" else run.run_id for run in live_runs()})
        named = [Path(w) for w in words if w.endswith((".yaml", ".yml"))]
        file = next((path for path in named if path.is_file()), None)
        if named and file is None:
            return []  # the file named is not there (yet): not the names of whatever else runs
        status = _live_status(words) if file is None else None
        if status is not None:
            file = Path(status["file"])
            if kind == "task":
                return sorted(t["task"] for t in status.get("tasks", []))
        return _in_file(kind, file) if file is not None else []
    except Exception:  # completion must never print a traceback into the shell
        return []


def _in_file(kind: str, file: Path, depth: int = 0) -> list[str]:
    """The names of a section of the file and of the files it includes (read as YAML, not checked: a
    file being written still completes)."""
    import yaml

    if kind not in (*SECTIONS, "task") or depth > 8:
        return []
    document = yaml.safe_load(file.read_text())
    if not isinstance(document, dict):
        return []
    section = document.get(SECTIONS.get(kind, "tasks"))
    found = {str(name) for name in section} if isinstance(section, (dict, list)) else set()
    included = document.get("include") or []
    for path in [included] if isinstance(included, str) else included:
        found.update(_in_file(kind, file.parent / str(path), depth + 1))
    return sorted(found)


def _live_status(words: list[str]) -> dict[str, Any] | None:
    """The status of the one live run the words name (`--subsystem`, `--run`), or None."""
    from pbo_runtime.ipc.control import ControlClient
    from pbo_runtime.ipc.runs import find_run

    def given(flag: str) -> str | None:
        return words[words.index(flag) + 1] if flag in words[:-1] else None

    run = find_run(given("--subsystem"), given("--run"))
    status = ControlClient(run.subsystem, run.run_id).call("status", None, timeout=LIVE_PATIENCE)
    return status if isinstance(status, dict) and "file" in status else None
