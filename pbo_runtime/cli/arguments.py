"""The command line's parser: a wrong argument exits 1, as the README says, with a "did you mean".

argparse exits 2 on a wrong argument; `pbo` keeps 2 for a run that failed. A misspelt verb or
flag is answered with the closest one, as a misspelt key in a YAML file is.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Sequence
from typing import NoReturn

from pbo_runtime.errors import closest_name

EXIT_WRONG_ARGUMENT = 1  # the same status as a file with errors (cli.main.EXIT_CONFIG)


class ArgumentParser(argparse.ArgumentParser):
    """argparse's parser, its errors worded with a hint and exiting 1; its sub-parsers are of this class too."""

    def parse_args(self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None) -> argparse.Namespace:  # type: ignore[override]
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:
            chosen = self._chosen_subparser(parsed)
            (chosen or self).error(f"unrecognized arguments: {' '.join(extras)}" + (chosen or self)._flag_hint(extras))
        return parsed

    def error(self, message: str) -> NoReturn:
        self.print_usage(sys.stderr)
        self.exit(EXIT_WRONG_ARGUMENT, f"{self.prog}: error: {message}{self._choice_hint(message)}\n")

    def _choice_hint(self, message: str) -> str:
        """For argparse's "invalid choice: 'chekc' (choose from 'check', ...)": the closest choice."""
        found = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)", message)
        if found is None:
            return ""
        close = closest_name(found[1], re.findall(r"'([^']*)'", found[2]))
        return f"\n  did you mean '{close}'?" if close else ""

    def _flag_hint(self, extras: list[str]) -> str:
        flags = [option for option in self._option_string_actions if option.startswith("--")]
        words = [word.split("=", 1)[0] for word in extras if word.startswith("-")]
        meant = [f"'{close}' for '{word}'" if len(words) > 1 else f"'{close}'"
                 for word in words for close in [closest_name(word, flags)] if close]
        return f"\n  did you mean {', '.join(meant)}?" if meant else ""

    def _chosen_subparser(self, parsed: argparse.Namespace) -> ArgumentParser | None:
        """The sub-parser of the verb given (`pbo run ...`: run's), down to the last level."""
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction):
                chosen = action.choices.get(getattr(parsed, action.dest or "", None) or "")
                if isinstance(chosen, ArgumentParser):
                    return chosen._chosen_subparser(parsed) or chosen
        return None


def host_addresses(args: argparse.Namespace) -> dict[str, str] | str:
    """--address HOST=ADDRESS, repeated: {host: address}, or what is wrong with one."""
    found: dict[str, str] = {}
    for given in getattr(args, "address", None) or []:
        host, mark, address = given.partition("=")
        if not mark or not host or not address:
            return f"--address takes HOST=ADDRESS, e.g. --address arm-b=10.0.0.2; got {given!r}"
        found[host] = address
    return found
