"""The verbs on files and the machine, declared once in `cli/verbs.py`: the parser, the docs and the
handlers agree with the table, and the table loads none of the wings behind the handlers."""

from __future__ import annotations

import argparse
import importlib
import json
import subprocess
import sys

import pytest

from pbo_runtime.cli.main import _parser
from pbo_runtime.cli.verbs import HOUSEKEEPING, OFFLINE, Command, verb_table
from tests.support import REPO


def leaves(commands: tuple[Command, ...], path: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], Command]]:
    """Each verb that runs, with the words that name it (`log export`: ("log", "export"))."""
    found = []
    for command in commands:
        if command.verbs:
            found.extend(leaves(command.verbs, (*path, command.name)))
        else:
            found.append(((*path, command.name), command))
    return found


VERBS = leaves(OFFLINE + HOUSEKEEPING)


def subparser(words: tuple[str, ...]) -> argparse.ArgumentParser:
    parser: argparse.ArgumentParser = _parser()
    for word in words:
        action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = action.choices[word]
    return parser


def test_the_docs_table_of_these_verbs_is_the_one_the_table_makes():
    text = (REPO / "docs" / "operator-commands.md").read_text()
    assert verb_table() in text, "regenerate it: python -c 'from pbo_runtime.cli.verbs import verb_table; print(verb_table())'"


@pytest.mark.parametrize(("words", "command"), VERBS, ids=lambda v: " ".join(v) if isinstance(v, tuple) else "")
def test_every_verb_is_a_cli_command_with_its_declared_arguments_and_a_handler_that_imports(words, command):
    parser = subparser(words)
    assert [a.dest for a in parser._actions if a.dest != "help"] == [argument.dest for argument in command.arguments]
    module, _, function = command.handler.partition(":")
    assert callable(getattr(importlib.import_module(module), function))


def test_a_verb_with_verbs_of_its_own_refuses_to_run_without_one(capsys):
    with pytest.raises(SystemExit) as exited:
        _parser().parse_args(["log"])
    assert exited.value.code == 1 and "required: COMMAND" in capsys.readouterr().err


@pytest.mark.multiprocess
@pytest.mark.parametrize("argv", [["--help"], ["--version"], ["run", "--help"], ["completion", "bash"]],
                         ids=lambda argv: " ".join(argv))
def test_help_version_and_completion_load_neither_numpy_nor_the_checker_nor_a_handler_they_do_not_run(argv):
    probe = ("import json, sys\nfrom pbo_runtime.cli.main import main\n"
             "try:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
             "print(json.dumps(sorted(sys.modules)), file=sys.stderr)")
    done = subprocess.run([sys.executable, "-c", probe, *argv], capture_output=True, text=True, timeout=60, cwd=REPO)
    loaded = set(json.loads(done.stderr.strip().splitlines()[-1]))
    assert not {"numpy", "mujoco", "pbo_runtime.config.checker", "pbo_runtime.supervisor.commands",
                "pbo_runtime.cli.running", "pbo_runtime.cli.check"} & loaded
    if argv == ["--version"]:  # the answer alone: no parser of every verb, no package metadata library
        assert not {"pbo_runtime.cli.parser", "pbo_runtime.objects.registry", "importlib.metadata", "argparse", "rich",
                    "dataclasses", "pbo_runtime.objects.dataclass_code"} & loaded
        assert done.stdout.startswith("pbo ")
