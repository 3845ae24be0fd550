"""The `pbo` command: check a subsystem file, run it, list the module library, copy out the examples, clean up.

Parsing and dispatch: the verbs are declared in `cli.verbs` and `supervisor.command_table`, each
naming its handler, imported here once its verb is known (so `pbo --help` loads none of them).

Exit status: 0 done, 1 the file has errors (or an operator command's arguments were refused),
2 the run failed, 3 an internal error (please report it). No traceback reaches the user unless --debug is given.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import time
import traceback
from typing import TYPE_CHECKING, Callable

from pbo_runtime.cli.completion import HIDDEN_VERB, complete
from pbo_runtime.cli.exits import EXIT_CONFIG, EXIT_INTERNAL, EXIT_RUN
from pbo_runtime.cli.parser import build_parser

if TYPE_CHECKING:
    from rich.console import Console

Handler = Callable[[argparse.Namespace, "Console", "Console"], int]


def main(argv: list[str] | None = None) -> int:
    # MuJoCo without its OpenGL context: nothing pbo runs renders, and importing it loads GLFW (0.1-0.3 s
    # per process: the CLI, the plant, each RTPU). A module that renders sets MUJOCO_GL (egl, glfw) itself.
    os.environ.setdefault("MUJOCO_GL", "disable")
    if argv is None:
        argv = sys.argv[1:]
    if argv[:1] == [HIDDEN_VERB]:  # the shell completing a name at the time of a <TAB>
        return complete(argv[1:])
    args = _parser().parse_args(argv)
    handler = _handler(args.handler)  # the verb's own code, imported only now
    from rich.console import Console

    from pbo_runtime.errors import ConfigErrors, MissingExtra, PboError
    from pbo_runtime.ipc.control import BadRequest
    from pbo_runtime.supervisor.failures import WrongArgument

    args.entered = time.monotonic()  # the start-up's time line (`pbo run`): the CLI's imports end here
    console = Console(highlight=False)
    errors = Console(stderr=True, highlight=False, soft_wrap=True)
    if not console.is_terminal:  # logs and CI: wide enough for the summary, no wrapping
        console = Console(highlight=False, width=140)
        errors = Console(stderr=True, highlight=False, width=140, soft_wrap=True)
    try:
        status = handler(args, console, errors)
        if status == EXIT_CONFIG:
            _say_where_an_example_is(args, errors)
        return status
    except ConfigErrors as exc:
        errors.print(str(exc), markup=False)
        _say_where_an_example_is(args, errors)
        return EXIT_CONFIG
    # arguments the run refused (an operator's command, `--config nope`): bad input
    except (BadRequest, WrongArgument, MissingExtra) as exc:
        errors.print(f"error: {exc}", markup=False)
        return EXIT_CONFIG
    except PboError as exc:
        errors.print(f"error: {exc}", markup=False)
        return EXIT_RUN
    except KeyboardInterrupt:
        return 130
    except (OSError, MemoryError) as exc:  # an OS limit met outside the run (too many open files reading the YAML)
        from pbo_runtime.ipc.limits import explain

        limit = explain(exc, f"pbo {args.command}")
        if limit is None or getattr(args, "debug", False):
            return _internal_error(args, errors)
        errors.print(f"error: {limit}", markup=False)
        return EXIT_RUN
    except Exception:
        return _internal_error(args, errors)


def _parser() -> argparse.ArgumentParser:
    """Every verb's parser, from the verb tables (`cli.parser`)."""
    return build_parser()


def _handler(name: str) -> Handler:
    """The function a verb names ("module:function"), imported now."""
    module, _, function = name.partition(":")
    handler: Handler = getattr(importlib.import_module(module), function)
    return handler


def _say_where_an_example_is(args: argparse.Namespace, errors: Console) -> None:
    """A FILE that is not there but names a shipped example (a command copied from a comment): where it is."""
    from pbo_runtime.cli.examples import missing_example_hint

    hint = missing_example_hint(args.file) if isinstance(getattr(args, "file", None), str) else None
    if hint is not None:
        errors.print(hint, markup=False)


def _internal_error(args: argparse.Namespace, errors: Console) -> int:
    """A bug: the last frames of the traceback and a request to report it (the whole traceback with --debug)."""
    if getattr(args, "debug", False):
        raise
    errors.print("internal error: pbo failed in a way it should not; please report this with the command you ran:", markup=False)
    errors.print(traceback.format_exc(limit=-3).rstrip(), markup=False)
    return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
