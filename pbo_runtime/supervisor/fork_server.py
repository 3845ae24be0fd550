"""The fork server: the run's children (the plant, each RTPU) forked from one warm interpreter.

A fresh interpreter per child imports numpy, MuJoCo and the runtime and loads the file again:
most of a start-up, and of a restart. The server does that once and forks a child per request,
as safely as a fresh interpreter: it forks only while single-threaded, runs SCHED_OTHER, forks
twice so the child is the supervisor's (a subreaper meanwhile), talks over a socketpair, makes no
shared object and dies with the supervisor. A server that cannot serve costs time, not the run:
that child starts as a fresh interpreter. docs/architecture.md ("A fork server") says why each
holds; PBO_FORK_SERVER=0 starts every child fresh.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import gc
import importlib
import inspect
import json
import os
import pickle
import select
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from typing import Any

from pbo_runtime.ipc.process import STOP_SIGNALS
from pbo_runtime.objects import dataclass_code

PR_SET_CHILD_SUBREAPER = 36
REQUEST_TIMEOUT = 60.0  # seconds for the server to import numpy and the module library on a busy machine
CLOSE_TIMEOUT = 2.0
END = b"end\n"  # the supervisor's last line to the server: its channel closing without it means the supervisor died
# What the runtime's public surface imports on first use (`pbo_runtime.arm_model` imports Pinocchio),
# imported by the server of a subsystem with a restart policy: a restarted controller's init would
# otherwise import it again, most of its spawn (docs/performance.md, a dead RTPU restarted alone).
WARM_FOR_RESTARTS = ("pinocchio",)
RUN_PRELOAD = ("pbo_runtime.supervisor.plant_host", "rtpu")  # what `pbo run`'s children run


class ForkServerUnavailable(Exception):
    """The fork server cannot start this child (it died, refused, or a fork failed): start it fresh."""


def forking_enabled() -> bool:
    """Whether children start from a fork server (PBO_FORK_SERVER=0: each one a fresh interpreter)."""
    return os.environ.get("PBO_FORK_SERVER", "1") != "0"


def _prctl(option: int, value: int) -> bool:
    try:
        return bool(ctypes.CDLL(None, use_errno=True).prctl(option, value, 0, 0, 0) == 0)
    except (OSError, AttributeError):
        return False


class ForkedProcess:
    """A child the fork server started, re-parented to this process: what the run uses of `subprocess.Popen`."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG)
            except ChildProcessError:  # reaped elsewhere: it has ended, how is not known
                self.returncode = -signal.SIGKILL
                return self.returncode
            if pid == self.pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        pause = 0.0005
        while self.poll() is None:
            if deadline is not None and time.monotonic() > deadline:
                raise subprocess.TimeoutExpired(f"pid {self.pid}", timeout or 0.0)
            time.sleep(pause)
            pause = min(pause * 2, 0.02)
        assert self.returncode is not None
        return self.returncode

    def send_signal(self, signum: int) -> None:
        if self.poll() is None:  # never a signal to a pid that may have been reused
            os.kill(self.pid, signum)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


class ForkServer:
    """The supervisor's end: start the server, ask it for children, end it."""

    def __init__(self, process: subprocess.Popen[bytes] | ForkedProcess, channel: socket.socket) -> None:
        self.process = process
        self._channel: socket.socket | None = channel
        self._replies = channel.makefile("rb")
        self._subreaper = False
        self.run_id = ""  # the run it serves, made with it (the supervisor takes it): the server takes part in its end
        self.warm_at = 0.0  # CLOCK_MONOTONIC second the server was ready to fork (0: not yet heard)
        self.awaits_run = False  # started without a file: it serves once `hand_over` gave it the loaded subsystem

    @classmethod
    def start(cls, file: str | None, preload: list[str], env: dict[str, str] | None = None, run_id: str = "") -> ForkServer:
        """A server for subsystem `file` that imports the `preload` modules (each one's `main` serves a request),
        a process of run `run_id` (`last_out`: if the supervisor dies, it may be the run's last one out).

        `file` None: a server started before the file is known (`pbo run`, before it parses its
        arguments); it imports what serves any file meanwhile and waits for `hand_over`."""
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        environment = dict(os.environ if env is None else env)
        openblas = environment.get("OPENBLAS_NUM_THREADS")
        environment["OPENBLAS_NUM_THREADS"] = "1"  # no thread in the server: it forks
        command = [sys.executable, "-m", "pbo_runtime.supervisor.fork_server", "--fd", str(theirs.fileno()),
                   "--parent", str(os.getpid()), *(["--file", file] if file is not None else []),
                   *(["--run-id", run_id] if run_id else []),
                   *(["--openblas-threads", openblas] if openblas is not None else []),
                   *(argument for module in preload for argument in ("--preload", module))]
        try:
            process = subprocess.Popen(command, stdin=subprocess.DEVNULL, start_new_session=True, env=environment,
                                       pass_fds=(theirs.fileno(),))
        except BaseException:
            ours.close()
            raise
        finally:
            theirs.close()
        server = cls(process, ours)
        server.run_id = run_id
        server.awaits_run = file is None
        return server

    @classmethod
    def fork_here(cls, preload: list[str], imports: tuple[str, ...], run_id: str) -> ForkServer:
        """A server forked from this process once it has imported `imports` (with OpenBLAS on one
        thread: the server forks), which the server then has without importing them again; it
        imports the `preload` modules meanwhile and waits for `hand_over`. Only while this process
        holds one thread and has made nothing the server must not hold (`pbo run`, before it parses).
        It is a process of run `run_id` from its start, as `start` makes one."""
        openblas = os.environ.get("OPENBLAS_NUM_THREADS")
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
        try:
            for module in imports:
                importlib.import_module(module)
        finally:  # this process's children started fresh get the environment it was given
            if openblas is None:
                os.environ.pop("OPENBLAS_NUM_THREADS", None)
            else:
                os.environ["OPENBLAS_NUM_THREADS"] = openblas
        if _threads() != 1:
            raise OSError("this process holds more than one thread: it cannot fork a server")
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        arguments = ["--fd", str(theirs.fileno()), "--parent", str(os.getpid()), "--forked", "--run-id", run_id,
                     *(["--openblas-threads", openblas] if openblas is not None else []),
                     *(argument for module in preload for argument in ("--preload", module))]
        sys.stdout.flush()  # (what either buffered would be written twice)
        sys.stderr.flush()
        try:
            pid = os.fork()
        except OSError:
            ours.close()
            theirs.close()
            raise
        if pid == 0:
            try:
                ours.close()
                os.setsid()  # as a server started with start_new_session
                devnull = os.open(os.devnull, os.O_RDONLY)
                os.dup2(devnull, 0)
                os.close(devnull)
                main(arguments)
            finally:
                os._exit(3)  # (main exits by itself; this only if it raised)
        theirs.close()
        server = cls(ForkedProcess(pid), ours)
        server.run_id = run_id
        server.awaits_run = True
        return server

    def hand_over(self, subsystem: Any) -> None:
        """Give a server started without a file its loaded and checked subsystem (it does not load the
        file again) and this process's environment now (what `pbo run` set after it started)."""
        if self._channel is None or not self.awaits_run:
            raise ValueError("hand_over is for a fork server started without a file, once")
        self.awaits_run = False
        run = {"environ": dict(os.environ), "file": subsystem.file}
        with contextlib.suppress(Exception):  # (a subsystem holding what cannot be pickled: the server loads the file)
            run["subsystem"] = pickle.dumps(subsystem).hex()
        with contextlib.suppress(OSError):  # a server gone: the first fork says so, and the children start fresh
            self._channel.sendall(json.dumps(run).encode() + b"\n")

    def fork(self, module: str, arguments: list[str]) -> ForkedProcess:
        """Start `python -m module arguments...` as a fork; ForkServerUnavailable if the server cannot."""
        return self.fork_all([(module, arguments)])[0]

    def fork_all(self, children: list[tuple[str, list[str]]]) -> list[ForkedProcess]:
        """Start each `python -m module arguments...` as a fork, in one request: one middle process forks
        them all, one after another. ForkServerUnavailable if the server cannot (then none was started)."""
        if not self._subreaper:
            self._subreaper = _prctl(PR_SET_CHILD_SUBREAPER, 1)
            if not self._subreaper:
                raise ForkServerUnavailable("this process cannot be a child subreaper (prctl refused)")
        if self._channel is None:
            raise ForkServerUnavailable("the fork server was ended")
        try:
            self._channel.settimeout(REQUEST_TIMEOUT)
            self._channel.sendall(json.dumps({"children": [[module, arguments] for module, arguments in children]}).encode()
                                  + b"\n")
            line = self._replies.readline()
        except OSError as exc:
            raise ForkServerUnavailable(f"the fork server (pid {self.process.pid}) did not answer: {exc}") from None
        finally:
            # the server reaped the middle process before it answered: the child is this process's already
            self.idle()
        if not line:
            code = self.process.poll()
            how = ("it ended" if code is None else f"exit status {code}" if code >= 0
                   else f"killed by {signal.Signals(-code).name}")
            raise ForkServerUnavailable(f"the fork server (pid {self.process.pid}) is gone ({how})")
        reply = json.loads(line)
        self.warm_at = self.warm_at or float(reply.get("warm_at", 0.0))
        if "error" in reply:
            for orphan in reply.get("orphans", []):  # forked before a fork failed: re-parented here, told to end
                with contextlib.suppress(ChildProcessError):
                    os.waitpid(int(orphan), 0)
            raise ForkServerUnavailable(reply["error"])
        return [ForkedProcess(int(pid)) for pid in reply["pids"]]

    def idle(self) -> None:
        """Between forks: not a subreaper (an orphan of a child's own child is not this process's to reap)."""
        if self._subreaper:
            _prctl(PR_SET_CHILD_SUBREAPER, 0)
            self._subreaper = False

    def release(self) -> None:
        """Tell the server to end (END, then EOF on its channel) without waiting for it."""
        if self._channel is not None:
            with contextlib.suppress(OSError):  # it is gone already
                self._channel.sendall(END)
            for closing in (self._replies, self._channel):
                with contextlib.suppress(OSError):
                    closing.close()
            self._channel = None
        self.idle()

    def close(self) -> None:
        """Release the server and reap it (SIGKILL if it has not gone within CLOSE_TIMEOUT; at once if it
        was never handed a run: it is still importing, and has no share in any run)."""
        never_used = self.awaits_run and self.process.poll() is None
        self.release()
        if never_used:
            self.process.kill()
        try:
            self.process.wait(timeout=CLOSE_TIMEOUT)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


# --- the server ---------------------------------------------------------------------------------


def _threads() -> int:
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
        self.refusal = ""  # why every request is refused ("": none is)
        self.warm_at = 0.0
        self.requests = channel.makefile("rb")

    def await_run(self) -> bool:
        """A server started without a file: the run `hand_over` gives it (False: the supervisor needs none)."""
        if not select.select([self.channel], [], [], 0)[0]:
            _warm_plants()  # the run is not there yet: its plant's simulator is imported meanwhile, whichever it is
        line = self.requests.readline()
        if not line or line == END:
            return False
        run = json.loads(line)
        environ = {**run["environ"], "OPENBLAS_NUM_THREADS": "1"}  # (the children's own is given back: `_child`)
        for key in set(os.environ) - set(environ):
            del os.environ[key]
        os.environ.update({key: value for key, value in environ.items() if os.environ.get(key) != value})
        if "subsystem" in run:
            self.subsystem = pickle.loads(bytes.fromhex(run["subsystem"]))  # from the process that started this one
        else:
            self.subsystem = _load(run["file"])
        return True

    def reply(self, answer: dict[str, Any]) -> None:
        self.channel.sendall(json.dumps({**answer, "warm_at": self.warm_at}).encode() + b"\n")

    def serve(self, request: dict[str, Any]) -> None:
        """Fork each child of the request ([module, argv] pairs, in order) from one middle process."""
        children = request.get("children")
        if self.refusal:
            return self.reply({"error": self.refusal})
        if not isinstance(children, list) or not children:
            return self.reply({"error": "the fork server was asked for no child"})
        for child in children:
            module, argv = child if isinstance(child, list) and len(child) == 2 else (child, None)
            if not isinstance(module, str) or module not in self.mains or not isinstance(argv, list):
                return self.reply({"error": f"the fork server does not start {module!r}"})
        threads = _threads()
        if threads != 1:
            return self.reply({"error": f"the fork server holds {threads} threads: a fork would copy their locks"})
        pid_read, pid_write = os.pipe()
        gos = [os.pipe() for _ in children]  # (read, write): a child starts once its write end says so
        # no stop while it forks: raised in the interpreter's fork hooks, it is only printed and lost
        signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)  # (the child takes them again: `_child`)
        middle = -1
        try:
            middle = os.fork()
        except OSError as exc:
            for fd in (pid_read, pid_write, *(end for go in gos for end in go)):
                os.close(fd)
            return self.reply({"error": f"the fork server could not fork: {exc}"})
        finally:
            if middle != 0:
                signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
        if middle == 0:  # the middle process: fork each child, say its pid, exit (the children are re-parented)
            try:
                os.close(pid_read)
                for _, go_write in gos:
                    os.close(go_write)
                self._fork_children(children, gos, pid_write)
            finally:
                os._exit(0)
        os.close(pid_write)
        for go_read, _ in gos:
            os.close(go_read)
        with os.fdopen(pid_read, "rb") as stream:
            pids = [int(said) for said in stream.read().split()]
        os.waitpid(middle, 0)
        if len(pids) != len(children):  # a fork failed: those forked see their go closed and exit (status 3)
            for _, go_write in gos:
                os.close(go_write)
            return self.reply({"error": "the fork server could not fork the child", "orphans": pids})
        self.reply({"pids": pids})
        for _, go_write in gos:  # the supervisor has their pids: they may start
            with contextlib.suppress(BrokenPipeError):  # (one killed meanwhile is the supervisor's to notice)
                os.write(go_write, b"g")
            os.close(go_write)

    def _fork_children(self, children: list[list[Any]], gos: list[tuple[int, int]], pid_write: int) -> None:
        """In the middle process: fork each child in turn and write its pid (a failed fork ends the list)."""
        for index, (module, argv) in enumerate(children):
            child = os.fork()
            if child == 0:
                os.close(pid_write)
                os.close(self.channel.fileno())  # the child holds no end of the channel: a dead server reads as EOF
                for other, (go_read, _) in enumerate(gos):
                    if other != index:
                        os.close(go_read)
                _child(module, self.mains[module], [str(a) for a in argv], self.subsystem, gos[index][0], self.parent,
                       self.openblas, self.run_id)
            os.write(pid_write, f"{child}\n".encode())


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
        try:
            server.mains = _warm_library(args.preload)
            if args.file is None and not server.await_run():
                raise Stop
            if args.file is not None:
                server.subsystem = _load(args.file)
            if server.subsystem is not None:
                _warm_subsystem(server.subsystem)
                if server.subsystem.plant is not None and not select.select([server.channel], [], [], 0)[0]:
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
