"""The `pbo` command's parser, made from the two verb tables: the offline verbs' and the operator's.

A verb's handler is set as its name ("module:function"), imported by `cli.main` once the verb is
known. An argument that completes a kind of name carries it as `complete_kind`, which the
completion script turns into a call to `pbo __complete` (`cli.completion`).
"""

from __future__ import annotations

import argparse
from typing import Any

from pbo_runtime.cli.arguments import ArgumentParser
from pbo_runtime.cli.verbs import HOUSEKEEPING, OFFLINE, Command
from pbo_runtime.supervisor.command_table import FORMAT, VERBS, WHICH_RUN, Argument

OPERATOR_HANDLER = "pbo_runtime.cli.operator:command"  # every operator verb: its request, then its reply printed


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """Every verb's parser; given the command line `argv`, only the verb it names gets its arguments
    (every verb is still named, for the usage and `--help`), which is all `argv` is parsed with."""
    chosen = _verb_named(argv)
    parser = ArgumentParser(prog="pbo", description="Reconfigurable real-time control from port-based objects.")
    parser.add_argument("--debug", action="store_true", help="show Python tracebacks of internal errors")
    parser.add_argument("--version", action=_Version, help="print the installed pbo-runtime's version and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in OFFLINE:
        _add_command(sub, command, chosen)
    for verb in VERBS:  # on a running subsystem (another terminal), over its 0600 control queue
        _add_verb(sub, verb.name, verb.help, (*verb.arguments, *WHICH_RUN, FORMAT), OPERATOR_HANDLER, chosen)
    for command in HOUSEKEEPING:
        _add_command(sub, command, chosen)
    return parser


def _verb_named(argv: list[str] | None) -> str | None:
    """The verb `argv` names (its first word that is not an option), if it is one; else None: every verb is built."""
    word = next((a for a in argv or () if not a.startswith("-")), None)
    known = {c.name for c in (*OFFLINE, *HOUSEKEEPING)} | {v.name for v in VERBS}
    return word if word in known else None


class _Version(argparse._VersionAction):
    """argparse's --version, the installed version looked up only when asked (the package metadata is slow to load)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        from pbo_runtime.objects.registry import installed_version

        self.version = f"pbo {installed_version()}"
        super().__call__(parser, namespace, values, option_string)


def _add_command(sub: Any, command: Command, chosen: str | None = None) -> None:
    """`command`'s parser; named only (no arguments, no verbs) if the command line chose another."""
    if not command.verbs:
        _add_verb(sub, command.name, command.help, command.arguments, command.handler, chosen)
        return
    parser = sub.add_parser(command.name, help=command.help)
    if chosen not in (None, command.name):
        return
    verbs = parser.add_subparsers(dest=f"{command.name}_command", required=True, metavar="COMMAND")
    for verb in command.verbs:
        _add_command(verbs, verb)


def _add_verb(sub: Any, name: str, help: str, arguments: tuple[Argument, ...], handler: str,
              chosen: str | None = None) -> None:
    parser = sub.add_parser(name, help=help)
    if chosen not in (None, name):
        return
    for argument in arguments:
        action = parser.add_argument(*argument.flags, **argument.argparse_options())
        if argument.complete is not None:
            action.complete_kind = argument.complete
    parser.set_defaults(handler=handler)
