"""The operator's verbs, declared once in the command table: the CLI, the docs and the supervisor agree."""

from __future__ import annotations

import argparse

import pytest

from pbo_runtime.cli import operator
from pbo_runtime.cli.main import _parser
from pbo_runtime.supervisor.commands import COMMANDS, VERBS, verb_table
from tests.conftest import REPO


def subparsers() -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in _parser()._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def test_the_docs_verb_table_is_the_one_the_command_table_makes():
    text = (REPO / "docs" / "operator-commands.md").read_text()
    assert verb_table() in text, "regenerate it: python -c 'from pbo_runtime.supervisor.commands import verb_table; print(verb_table())'"


@pytest.mark.parametrize("verb", VERBS, ids=lambda verb: verb.name)
def test_every_verb_is_a_cli_command_with_its_declared_arguments_and_a_runner(verb):
    parser = subparsers()[verb.name]
    declared = [argument.dest for argument in verb.arguments] + ["subsystem"]
    assert [a.dest for a in parser._actions if a.dest != "help"] == declared
    assert verb.name in operator._RUNNERS


def test_the_cli_runs_no_verb_the_table_does_not_declare():
    assert set(operator._RUNNERS) == set(COMMANDS)


def test_a_verbs_request_takes_its_keys_from_the_table_and_parses_numbers():
    assert COMMANDS["job"].request({"name": "move", "values": ["0.5", "-1"]}) == {"job": "move", "object": [0.5, -1.0]}
    assert COMMANDS["job"].request({"name": "move", "values": []}) == {"job": "move", "object": None}
    assert COMMANDS["on"].request({"task": "pid"}) == {"task": "pid"}
    assert COMMANDS["status"].request({}) == {}
