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

import contextlib
import ctypes
import gc
import importlib
import json
import os
import pickle
import signal
import socket
import subprocess
import sys
import time
from typing import Any

from pbo_runtime.supervisor.fork_server_process import END, thread_count
from pbo_runtime.supervisor.fork_server_process import main as serve

PR_SET_CHILD_SUBREAPER = 36
REQUEST_TIMEOUT = 60.0  # seconds for the server to import numpy and the module library on a busy machine
CLOSE_TIMEOUT = 2.0
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
        if thread_count() != 1:
            raise OSError("this process holds more than one thread: it cannot fork a server")
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        arguments = ["--fd", str(theirs.fileno()), "--parent", str(os.getpid()), "--forked", "--run-id", run_id,
                     *(["--openblas-threads", openblas] if openblas is not None else []),
                     *(argument for module in preload for argument in ("--preload", module))]
        sys.stdout.flush()  # (what either buffered would be written twice)
        sys.stderr.flush()
        # what both hold stays out of both's collections: a collection walking it writes to each
        # object's header, and each process would copy every page of what they share
        gc.freeze()
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



def main(argv: list[str] | None = None) -> int:
    """`python -m pbo_runtime.supervisor.fork_server`: the server's own process (`supervisor.fork_server_process`)."""
    return serve(argv)


if __name__ == "__main__":
    sys.exit(main())
