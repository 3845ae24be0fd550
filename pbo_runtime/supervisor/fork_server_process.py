"""The fork server's own process (`supervisor.fork_server`): what it imports before it forks, and how
it forks the run's children.

A child is forked by a middle process that exits at once, so the child is re-parented to the
supervisor (a subreaper while it asks). The plant's middle process of `pbo run` is forked
early, at the server's start (`EarlyPlant`): it imports the plant's simulator while the server
imports the module library, each on a CPU of its own beside the CLI's load and check, instead of
one after the other in the server.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import importlib
import inspect
import json
import os
import pickle
import select
import signal
import socket
import sys
import time
from collections.abc import Callable
from typing import Any

from pbo_runtime.ipc.process import STOP_SIGNALS
from pbo_runtime.objects import dataclass_code

PLANT_HOST = "pbo_runtime.supervisor.plant_host"  # what `pbo run`'s plant runs
END = b"end\n"  # the supervisor's last line to the server: its channel closing without it means the supervisor died
# What the runtime's public surface imports on first use (`pbo_runtime.arm_model` imports Pinocchio),
# imported by the server of a subsystem with a restart policy: a restarted controller's init would
# otherwise import it again, most of its spawn (docs/performance.md, a dead RTPU restarted alone).
WARM_FOR_RESTARTS = ("pinocchio",)


def thread_count() -> int:
    """How many threads this process holds (0: cannot tell): a process forks only while it holds one."""
    try:
        return len(os.listdir("/proc/self/task"))
    except OSError:
        return 0  # cannot tell: refused below


def _main_of(module: str) -> Callable[..., int]:
    """What `python -m module` runs: the module's main(), or its package's __main__.main()."""
    imported = importlib.import_module(module)
    if not hasattr(imported, "main"):
        imported = importlib.import_module(f"{module}.__main__")
    main: Callable[..., int] = imported.main
    return main


def _warm_library(preload: list[str]) -> dict[str, Callable[..., int]]:
    """Import each preloaded module's `main` and the module library: what serves any file."""
    title = importlib.import_module("setproctitle")  # imported once here, not in each child
    title.setproctitle(title.getproctitle())  # it takes the command line's memory now, before `await_run` changes the environment

    mains = {module: _main_of(module) for module in preload}
    from pbo_runtime.objects import registry

    registry.import_library()  # what a task spawned live may need: a forked RTPU (a restarted one too) has it all
    return mains


def _warm_plants() -> None:
    """Every registered plant's `warm()` (its simulator's imports): done while the server would only wait for its run."""
    from pbo_runtime.objects import registry

    for name in registry.names(registry.PLANTS):
        with contextlib.suppress(Exception):  # the plant that is run imports it again, and reports a failure
            warm = getattr(registry.plant_class(name), "warm", None)
            if callable(warm):
                warm()


def _load(file: str) -> Any:
    """The subsystem in `file`, loaded and checked; None if it has errors (each child loads it and reports them)."""
    from pbo_runtime.config.loader import load_subsystem
    from pbo_runtime.errors import PboError

    try:
        return load_subsystem(file)
    except (PboError, OSError):
        return None


def _warm_subsystem(subsystem: Any) -> None:
    """Look up the subsystem's modules, plant and drivers, and import what the modules and drivers
    import only once made. Not the plant's simulator: `_warm_plants` imports it while no request
    for the children has come (before the run is handed over, or after this, until the CLI has
    made its table); a request that came first is served at once and the plant imports it forked."""
    from pbo_runtime.objects import registry
    from pbo_runtime.reports.log_notes import run_metadata

    run_metadata(subsystem, "real")  # the packages' versions it reads, read once here (each a parse of METADATA)
    if any(rtpu.restart is not None for rtpu in subsystem.rtpus):
        for module in WARM_FOR_RESTARTS:  # (the run's first children skip the import too)
            with contextlib.suppress(Exception):  # a child that needs it imports it, and reports a failure, as a fresh one would
                importlib.import_module(module)
    lookups = [(registry.module_class, task.module) for task in subsystem.tasks.values()]
    lookups += [(registry.driver_class, device.driver) for device in subsystem.devices.values()]
    if subsystem.plant is not None:
        with contextlib.suppress(Exception):  # (the plant looks it up again and reports the failure)
            registry.plant_class(subsystem.plant.type)
    for look_up, name in lookups:
        with contextlib.suppress(Exception):  # the child that needs it looks it up again and reports the failure
            found = look_up(name)
            warm = getattr(found, "warm", None)  # what the class imports only once one is made
            if callable(warm):
                warm()


def _child(module: str, main: Callable[..., int], argv: list[str], subsystem: Any, go: int, parent: int,
           openblas: str | None, run_id: str) -> None:
    """In the forked child: wait for the go (by then the supervisor's own), run `main`, never return.

    Until its main takes its share of the run, it expects it as the server does (`last_out`): a
    supervisor that dies while the child starts may leave the child the run's last process."""
    code = 3
    from pbo_runtime.ipc.process import Stop
    from pbo_runtime.supervisor import last_out

    try:
        last_out.forget_inherited()
        if run_id:
            last_out.expect(run_id)
        import setproctitle

        # its command line in ps and /proc is the one a fresh interpreter would have had, not the server's
        setproctitle.setproctitle(" ".join([sys.executable, "-m", module, *argv]))
        # the go comes once the server reaped the middle process, which re-parented this one as it exited
        if os.read(go, 1) != b"g":  # the server died before the supervisor had this pid
            raise SystemExit(3)
        os.close(go)
        if os.getppid() != parent:  # adopted by another: the supervisor died
            raise SystemExit(3)
        os.setsid()
        for signum in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP, signal.SIGALRM, signal.SIGCHLD, signal.SIGPIPE):
            signal.signal(signum, signal.SIG_DFL if signum != signal.SIGPIPE else signal.SIG_IGN)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)  # (blocked while the server forked)
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))  # as a fresh interpreter starts
        if openblas is None:
            os.environ.pop("OPENBLAS_NUM_THREADS", None)
        else:
            os.environ["OPENBLAS_NUM_THREADS"] = openblas
        import random

        random.seed()  # its own random streams, as a fresh interpreter has
        if "numpy.random" in sys.modules:  # (not imported yet: a child that imports it has it seeded from the OS)
            sys.modules["numpy.random"].seed()
        keywords = {"subsystem": subsystem} if subsystem is not None and "subsystem" in inspect.signature(main).parameters else {}
        code = main(argv, **keywords)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    except Stop:  # stopped before its main could take the stop (or again, while it stopped): no traceback
        code = 0
    except BaseException:
        import traceback

        traceback.print_exc()
        code = 1
    finally:
        try:
            last_out.leave()  # (its main left already, unless it never ran)
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code)


class _Server:
    """The server's state: what a request may run, the loaded subsystem, where replies go."""

    def __init__(self, channel: socket.socket, parent: int, openblas: str | None, run_id: str = "") -> None:
        self.channel = channel
        self.parent = parent
        self.run_id = run_id
        self.openblas = openblas
        self.mains: dict[str, Callable[..., int]] = {}
        self.subsystem: Any = None
        self.early_plant: EarlyPlant | None = None  # the plant's middle process, forked early, until it is asked
        self.refusal = ""  # why every request is refused ("": none is)
        self.warm_at = 0.0
        self.requests = channel.makefile("rb")

    def await_run(self) -> bool:
        """A server started without a file: the run `hand_over` gives it (False: the supervisor needs none)."""
        if self.early_plant is None and not select.select([self.channel], [], [], 0)[0]:
            _warm_plants()  # the run is not there yet: its plant's simulator is imported meanwhile, whichever it is
        line = self.requests.readline()
        if not line or line == END:
            return False
        run = json.loads(line)
        _take_environment(run["environ"])
        if "subsystem" in run:
            self.subsystem = pickle.loads(bytes.fromhex(run["subsystem"]))  # from the process that started this one
        else:
            self.subsystem = _load(run["file"])
        return True

    def reply(self, answer: dict[str, Any]) -> None:
        self.channel.sendall(json.dumps({**answer, "warm_at": self.warm_at}).encode() + b"\n")

    def serve(self, request: dict[str, Any]) -> None:
        """Fork each child of the request ([module, argv] pairs, in order) from one middle process (the
        plant's from its own, forked early, if there is one: `EarlyPlant`)."""
        children = request.get("children")
        if self.refusal:
            return self.reply({"error": self.refusal})
        if not isinstance(children, list) or not children:
            return self.reply({"error": "the fork server was asked for no child"})
        for child in children:
            module, argv = child if isinstance(child, list) and len(child) == 2 else (child, None)
            if not isinstance(module, str) or module not in self.mains or not isinstance(argv, list):
                return self.reply({"error": f"the fork server does not start {module!r}"})
        threads = thread_count()
        if threads != 1:
            return self.reply({"error": f"the fork server holds {threads} threads: a fork would copy their locks"})
        early, self.early_plant = self.early_plant, None  # (one plant a run: asked once)
        plant = next((i for i, (module, _) in enumerate(children) if module == PLANT_HOST), -1) if early else -1
        if early is not None and (plant < 0 or not early.ask([str(a) for a in children[plant][1]])):
            early.end()
            early, plant = None, -1
        try:
            pids, gos = self._fork([child for index, child in enumerate(children) if index != plant])
            if early is not None:  # (forked meanwhile)
                plant_pid = early.answer()
                if plant_pid is None:  # it died before it forked: the plant is forked here
                    early.end()
                    early = None
                    [plant_pid], more = self._fork([children[plant]], orphans=pids, gos=gos)
                    gos += more
                pids.insert(plant, plant_pid)
        except _ForkFailed as failed:
            if early is not None:  # the plant, if it was forked, sees its go closed and ends
                if early.pid:
                    failed.orphans += [pid for pid in [early.answer()] if pid is not None]
                early.end()
            return self.reply({"error": str(failed), "orphans": failed.orphans})
        self.reply({"pids": pids})
        if early is not None:
            gos.insert(plant, early.go)
        for go_write in gos:  # the supervisor has their pids: they may start
            with contextlib.suppress(BrokenPipeError):  # (one killed meanwhile is the supervisor's to notice)
                os.write(go_write, b"g")
            os.close(go_write)

    def _fork(self, children: list[list[Any]], orphans: list[int] | None = None,
              gos: list[int] | None = None) -> tuple[list[int], list[int]]:
        """Fork each child from one middle process: their pids, and the write end of each one's go pipe.
        _ForkFailed if one fork failed: those forked, and the `orphans` already forked (`gos` theirs), end."""
        if not children:
            return [], []
        pid_read, pid_write = os.pipe()
        pipes = [os.pipe() for _ in children]  # (read, write): a child starts once its write end says so
        # no stop while it forks: raised in the interpreter's fork hooks, it is only printed and lost
        signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)  # (the child takes them again: `_child`)
        middle = -1
        try:
            middle = os.fork()
        except OSError as exc:
            for fd in (pid_read, pid_write, *(end for pipe in pipes for end in pipe), *(gos or [])):
                os.close(fd)
            raise _ForkFailed(f"the fork server could not fork: {exc}", list(orphans or [])) from None
        finally:
            if middle != 0:
                signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
        if middle == 0:  # the middle process: fork each child, say its pid, exit (the children are re-parented)
            try:
                os.close(pid_read)
                for fd in (*(go_write for _, go_write in pipes), *(gos or [])):
                    os.close(fd)
                self._fork_children(children, pipes, pid_write)
            finally:
                os._exit(0)
        os.close(pid_write)
        for go_read, _ in pipes:
            os.close(go_read)
        with os.fdopen(pid_read, "rb") as stream:
            pids = [int(said) for said in stream.read().split()]
        os.waitpid(middle, 0)
        if len(pids) != len(children):  # a fork failed: those forked see their go closed and exit (status 3)
            for fd in (*(go_write for _, go_write in pipes), *(gos or [])):
                os.close(fd)
            raise _ForkFailed("the fork server could not fork the child", [*(orphans or []), *pids])
        return pids, [go_write for _, go_write in pipes]

    def _fork_children(self, children: list[list[Any]], gos: list[tuple[int, int]], pid_write: int) -> None:
        """In the middle process: fork each child in turn and write its pid (a failed fork ends the list)."""
        for index, (module, argv) in enumerate(children):
            child = os.fork()
            if child == 0:
                os.close(pid_write)
                os.close(self.channel.fileno())  # the child holds no end of the channel: a dead server reads as EOF
                if self.early_plant is not None:
                    self.early_plant.close_in_child()
                for other, (go_read, _) in enumerate(gos):
                    if other != index:
                        os.close(go_read)
                _child(module, self.mains[module], [str(a) for a in argv], self.subsystem, gos[index][0], self.parent,
                       self.openblas, self.run_id)
            os.write(pid_write, f"{child}\n".encode())


class _ForkFailed(Exception):
    """A request that could not be served whole: why, and the pids of the children forked before (each ends)."""

    def __init__(self, message: str, orphans: list[int]) -> None:
        super().__init__(message)
        self.orphans = orphans


def _take_environment(environ: dict[str, str]) -> None:
    """This process's environment becomes `environ` (the supervisor's now), with OpenBLAS on one thread
    while it forks (the children's own is given back: `_child`)."""
    environ = {**environ, "OPENBLAS_NUM_THREADS": "1"}
    for key in set(os.environ) - set(environ):
        del os.environ[key]
    os.environ.update({key: value for key, value in environ.items() if os.environ.get(key) != value})


class EarlyPlant:
    """The server's end of the plant's middle process, forked at the server's start (`_early_plant`):
    asked once, it forks the plant and exits, as `_Server._fork`'s middle does."""

    def __init__(self, pid: int, ask: int, answer: int, go: int) -> None:
        self.pid = pid
        self.ask_fd, self.answer_fd, self.go = ask, answer, go  # go: the plant's go pipe, written by the server

    @classmethod
    def fork(cls, server: _Server) -> EarlyPlant | None:
        """Forked now (None if it could not be: the server then forks the plant itself)."""
        ask_read, ask_write = os.pipe()
        answer_read, answer_write = os.pipe()
        go_read, go_write = os.pipe()
        try:
            pid = os.fork()
        except OSError:
            for fd in (ask_read, ask_write, answer_read, answer_write, go_read, go_write):
                os.close(fd)
            return None
        if pid == 0:
            for fd in (ask_write, answer_read, go_write):
                os.close(fd)
            _early_plant(server, ask_read, answer_write, go_read)
        for fd in (ask_read, answer_write, go_read):
            os.close(fd)
        return cls(pid, ask_write, answer_read, go_write)

    def ask(self, argv: list[str]) -> bool:
        """Ask it to fork the plant with `argv`, in this process's environment (False: it is gone)."""
        try:
            os.write(self.ask_fd, json.dumps({"argv": argv, "environ": dict(os.environ)}).encode() + b"\n")
            return True
        except OSError:
            return False

    def answer(self) -> int | None:
        """The plant's pid once it has exited (so the plant is re-parented); None if it died before it forked."""
        said = b""
        with contextlib.suppress(OSError):
            while not said.endswith(b"\n"):
                read = os.read(self.answer_fd, 64)
                if not read:
                    break
                said += read
        with contextlib.suppress(ChildProcessError):
            os.waitpid(self.pid, 0)
        self.pid = 0
        return int(said) if said.endswith(b"\n") else None

    def end(self) -> None:
        """Not asked, or its request failed: it ends at once (it holds nothing), and a plant it forked sees
        its go closed and ends (status 3)."""
        for fd in (self.ask_fd, self.answer_fd, self.go):
            with contextlib.suppress(OSError):
                os.close(fd)
        if self.pid:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGKILL)  # (still importing, it would end only once it read the EOF)
            with contextlib.suppress(ChildProcessError):
                os.waitpid(self.pid, 0)
            self.pid = 0

    def close_in_child(self) -> None:
        """In another child of the server: it holds none of these ends (a dead server reads as EOF)."""
        for fd in (self.ask_fd, self.answer_fd, self.go):
            os.close(fd)


def _early_plant(server: _Server, ask: int, answer: int, go: int) -> None:
    """The plant's middle process: import the plant's simulator, wait to be asked, fork the plant, exit."""
    from pbo_runtime.ipc.process import Stop, become_child
    from pbo_runtime.supervisor import last_out

    try:
        os.close(server.channel.fileno())  # the supervisor's channel is the server's alone
        last_out.forget_inherited()  # it makes and opens nothing of the run's: no share in its end
        become_child(os.getppid())  # it ends with the server
        import setproctitle

        setproctitle.setproctitle(" ".join([sys.executable, "-m", "pbo_runtime.supervisor.fork_server", "--preload",
                                            PLANT_HOST, "--run-id", server.run_id, "--early"]))
        main = _main_of(PLANT_HOST)
        _warm_plants()
        dataclass_code.save()  # the plant's classes it made, if new, while it waits (the server saves its own)
        gc.freeze()  # (as the server's: `_serve`)
        with os.fdopen(ask, "rb") as asked:
            line = asked.readline()
        if not line:  # not asked: the run needs no plant, or the server ended
            os._exit(0)
        if thread_count() != 1:  # a fork would copy their locks: the server forks the plant itself
            os._exit(0)
        request = json.loads(line)
        _take_environment(request["environ"])
        signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)  # (as `_Server._fork`)
        plant = os.fork()
        if plant == 0:
            os.close(answer)
            _child(PLANT_HOST, main, request["argv"], None, go, server.parent, server.openblas, server.run_id)
        os.write(answer, f"{plant}\n".encode())
    except Stop:
        pass
    os._exit(0)


def main(argv: list[str] | None = None) -> int:
    dataclass_code.install()  # (a server forked from the CLI has it already)
    parser = argparse.ArgumentParser(prog="python -m pbo_runtime.supervisor.fork_server")
    parser.add_argument("--fd", type=int, required=True, help="this end of the supervisor's socketpair")
    parser.add_argument("--parent", type=int, required=True)
    parser.add_argument("--file", default=None, help="the subsystem file the children run (absent: given by `hand_over`)")
    parser.add_argument("--preload", action="append", default=[], help="a module whose main() a request may run")
    parser.add_argument("--openblas-threads", default=None, help="the children's OPENBLAS_NUM_THREADS (unset if absent)")
    parser.add_argument("--run-id", default="", help="the run it serves: it takes part in its end (last_out)")
    parser.add_argument("--forked", action="store_true", help="forked from its supervisor (`ForkServer.fork_here`)")
    args = parser.parse_args(argv)
    if args.forked:  # its command line in ps and /proc is the one a server started fresh would have had
        import setproctitle

        setproctitle.setproctitle(" ".join([sys.executable, "-m", "pbo_runtime.supervisor.fork_server", *(argv or [])]))
    from pbo_runtime.ipc.process import Stop, become_child, supervisor_dying
    from pbo_runtime.supervisor import last_out

    if args.run_id:
        last_out.expect(args.run_id)
    server = _Server(socket.socket(fileno=args.fd), args.parent, args.openblas_threads, args.run_id)
    try:
        become_child(args.parent)
    except SystemExit:
        last_out.leave()
        raise
    try:
        if args.file is None and PLANT_HOST in args.preload and len(args.preload) > 1:  # `pbo run`'s
            server.early_plant = EarlyPlant.fork(server)
        try:
            server.mains = _warm_library(args.preload)
            if args.file is None and not server.await_run():
                raise Stop
            if args.file is not None:
                server.subsystem = _load(args.file)
            if server.subsystem is not None:
                if server.subsystem.plant is None and server.early_plant is not None:
                    server.early_plant.end()
                    server.early_plant = None
                _warm_subsystem(server.subsystem)
                if (server.subsystem.plant is not None and server.early_plant is None
                        and not select.select([server.channel], [], [], 0)[0]):
                    _warm_plants()  # the children are not asked for yet: the plant, forked then, starts warm
        except (Stop, BrokenPipeError, ConnectionResetError):
            raise
        except Exception as exc:  # every request is refused with the reason: the children start fresh
            server.refusal = f"the fork server could not import what the children run: {type(exc).__name__}: {exc}"
        # what the children inherit stays out of their collections: a collection walking it would
        # write to each object's header, copying every page of it (most of a forked child's start)
        gc.freeze()
        server.warm_at = time.monotonic()
        for line in server.requests:
            if line == END:
                break
            server.serve(json.loads(line))
        else:
            supervisor_dying()  # its end of the channel closed without a word (its death signal may come after)
    except (BrokenPipeError, ConnectionResetError):
        supervisor_dying()
    except Stop:
        pass
    if server.early_plant is not None:
        server.early_plant.end()
    # EOF: the server made no shared object; if the supervisor died, it may be the run's last process
    # out (before the children were started, or with a restart policy). Tearing down an interpreter
    # that holds numpy, MuJoCo and the module library takes a while: it is skipped.
    last_out.leave()
    dataclass_code.save()  # the module library's methods it compiled, if any (its children never save)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


if __name__ == "__main__":
    sys.exit(main())
