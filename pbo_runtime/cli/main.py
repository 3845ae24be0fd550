"""The `pbo` command: check a subsystem file, run it, list the module library, copy out the examples, clean up.

Parsing and dispatch: the verbs are declared in `cli.verbs` and `supervisor.command_table`, each
naming its handler, imported here once its verb is known (so `pbo --help` loads none of them).

Exit status: 0 done, 1 the file has errors (or an operator command's arguments were refused),
2 the run failed, 3 an internal error (please report it). No traceback reaches the user unless --debug is given.
"""

from __future__ import annotations

import importlib
import os
import sys
import time

from pbo_runtime.cli.exits import EXIT_CONFIG, EXIT_INTERNAL, EXIT_RUN

TYPE_CHECKING = False  # typing's, without importing typing (nor argparse): `pbo --version` answers first
if TYPE_CHECKING:
    import argparse
    from collections.abc import Callable

    from rich.console import Console

    from pbo_runtime.supervisor.fork_server import ForkServer

    Handler = Callable[[argparse.Namespace, Console, Console], int]


# What `pbo run` and its fork server both import, imported before the server is forked from it (not
# the loader, the checker and the YAML parser: only the CLI loads the file, after the fork)
SHARED_IMPORTS = ("numpy", "pbo_runtime.config.model", "pbo_runtime.table.table", "pbo_runtime.ipc.messages",
                  "pbo_runtime.clock.clocks", "pbo_runtime.clock.lockstep", "pbo_runtime.edit.wire",
                  "pbo_runtime.supervisor.launch", "pbo_runtime.supervisor.reconfiguration",
                  "pbo_runtime.reports.log_notes")


def main(argv: list[str] | None = None) -> int:
    # MuJoCo without its OpenGL context: nothing pbo runs renders, and importing it loads GLFW (0.1-0.3 s
    # per process: the CLI, the plant, each RTPU). A module that renders sets MUJOCO_GL (egl, glfw) itself.
    os.environ.setdefault("MUJOCO_GL", "disable")
    command_line = argv is None
    if argv is None:
        argv = sys.argv[1:]
    if argv == ["--version"]:  # what argparse's --version prints, without building every verb's parser first
        from pbo_runtime.objects.version import installed_version

        print(f"pbo {installed_version()}")
        return 0
    if command_line and argv[:1] == ["run"] and "--one-process" in argv:
        _with_fixed_hashing(argv)  # before the parser is imported: the interpreter that runs is the next one
    _keep_dataclass_code()
    fork_server = _early_fork_server(argv)
    try:
        return _main(argv, command_line, fork_server)
    finally:
        if fork_server is not None:  # (ended already where a run took it)
            fork_server.close()


def _main(argv: list[str], command_line: bool, fork_server: ForkServer | None) -> int:
    from pbo_runtime.cli.completion import HIDDEN_VERB, complete

    if argv[:1] == [HIDDEN_VERB]:  # the shell completing a name at the time of a <TAB>
        return complete(argv[1:])
    args = _parser(argv).parse_args(argv)
    args.fork_server = fork_server
    if command_line and getattr(args, "one_process", False):
        _with_fixed_hashing(argv)
    handler = _handler(args.handler)  # the verb's own code, imported only now
    from typing import cast

    from pbo_runtime.cli.console import LazyConsole
    from pbo_runtime.errors import ConfigErrors, PboError

    args.entered = time.monotonic()  # the start-up's time line (`pbo run`): the CLI's imports end here
    # rich's consoles, made once used (`cli.console`): `pbo run` off a terminal makes them after `on`
    lazy = LazyConsole()
    console, errors = cast("Console", lazy), cast("Console", LazyConsole(stderr=True, width_from=lazy))
    try:
        status = handler(args, console, errors)
        if status == EXIT_CONFIG:
            _say_where_an_example_is(args, errors)
        return status
    except ConfigErrors as exc:
        errors.print(str(exc), markup=False)
        _say_where_an_example_is(args, errors)
        return EXIT_CONFIG
    except _refused_arguments() as exc:  # arguments the run refused (an operator's command, `--config nope`): bad input
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


def _keep_dataclass_code() -> None:
    """Dataclass methods run from the code kept by an earlier process, before the first dataclass is
    made (the fork server, forked later, inherits it); what this process compiled is kept at exit."""
    import atexit

    from pbo_runtime.objects import dataclass_code

    if dataclass_code.install():
        atexit.register(dataclass_code.save)


def _with_fixed_hashing(argv: list[str]) -> None:
    """`--one-process`: the tasks run in this interpreter, which must hash strings as the run's processes
    do (`clock.run_clock`); if it does not, it is replaced by one that does (never returns then)."""
    if os.environ.get("PYTHONHASHSEED") != "0":
        os.execve(sys.executable, [sys.executable, "-m", "pbo_runtime.cli", *argv], {**os.environ, "PYTHONHASHSEED": "0"})


def _early_fork_server(argv: list[str]) -> ForkServer | None:
    """`pbo run` on the real clock: the run's fork server, forked from the CLI before its parser: its
    own imports (MuJoCo, the module library, what the children run) overlap the CLI's parser,
    load and check; it is handed the file once the CLI has loaded it (`cli.running`). The arguments are not parsed yet: a run that
    turns out not to need it (a wrong argument, the simulated clock) ends it unused; where the guess
    says no (no such file, an application, --help), the run starts it later (`cli.running`)."""
    if argv[:1] != ["run"] or any(a in ("sim", "-h", "--help", "--one-process") or a.endswith("=sim") for a in argv):
        return None
    files = [a for a in argv[1:] if a.endswith((".yaml", ".yml")) and os.path.isfile(a)]
    from pbo_runtime.config.file_kind import is_application_file
    from pbo_runtime.supervisor.fork_server import RUN_PRELOAD, ForkServer, forking_enabled

    if len(files) != 1 or is_application_file(files[0]) or not forking_enabled():
        return None
    try:  # forked once the imports both need are done (numpy, the model, the table, the queues, the
        # clocks): each is imported once, in the CLI, which would import it later
        from pbo_runtime.ipc.shm import new_run_id

        # the run's id, which the supervisor takes: the server takes part in the run's end from its start
        return ForkServer.fork_here(list(RUN_PRELOAD), SHARED_IMPORTS, new_run_id())
    except OSError:
        return None  # the run starts one later, and says why if it cannot


def _refused_arguments() -> tuple[type[Exception], ...]:
    """The errors that mean the arguments were refused, imported only once one was raised (the operator
    commands' module is most of what `pbo check` would otherwise import for this line)."""
    from pbo_runtime.errors import MissingExtra
    from pbo_runtime.ipc.control import BadRequest
    from pbo_runtime.supervisor.failures import WrongArgument

    return BadRequest, WrongArgument, MissingExtra


def _parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """Every verb's parser, from the verb tables (`cli.parser`), the arguments only of the verb `argv` names."""
    from pbo_runtime.cli.parser import build_parser

    return build_parser(argv)


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
    import traceback

    if getattr(args, "debug", False):
        raise
    errors.print("internal error: pbo failed in a way it should not; please report this with the command you ran:", markup=False)
    errors.print(traceback.format_exc(limit=-3).rstrip(), markup=False)
    return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
