"""The run of an application file the HMI started: `pbo run APP.yaml`, as a person types it.

The HMI starts the CLI itself, so the run is the one the command line makes: the application's
runner, one supervisor per subsystem, the stages joined (`supervisor.application_runner`,
`supervisor.stages`). It runs in the served folder (its run directory is `runs/` there), in a
session of its own, and is stopped with SIGINT, as Ctrl-C stops it; the server stops it when it
ends. Its output is kept, the last lines of it, for the page to show, and so is how many stages
each subsystem has done (its "stage N done here" lines): the page finds each subsystem's stage by it.
"""

from __future__ import annotations

import collections
import os
import re
import signal
import subprocess
import sys
import threading
from typing import Any

CLOCKS = ("real", "sim")
KEPT_LINES = 200  # the page shows the last few; the run directory has the whole summary
STAGE_DONE = re.compile(r"^\[([^\]]+)\] pbo: stage (\d+) done here")  # a subsystem's part of a stage ended (supervisor.stages)
STOP_GRACE = 30.0  # seconds the runner gets to stop its subsystems after SIGINT before it is killed


class RunRefused(Exception):
    """The run was not started: one is running already, or the request is wrong."""


class ApplicationRun:
    """At most one run of `file` at a time, started from `folder`."""

    def __init__(self, file: str, folder: str) -> None:
        self.file = file
        self.folder = folder
        self.clock = ""
        self._process: subprocess.Popen[str] | None = None
        self._lines: collections.deque[str] = collections.deque(maxlen=KEPT_LINES)
        self._done: dict[str, int] = {}  # subsystem -> the stages it has done in this run
        self._lock = threading.Lock()
        self._reader: threading.Thread | None = None

    def start(self, clock: str) -> dict[str, Any]:
        if clock not in CLOCKS:
            raise RunRefused(f"clock must be one of {', '.join(CLOCKS)}, got {clock!r}")
        with self._lock:
            if self._process is not None and self._process.poll() is None:
                raise RunRefused(f"the application runs already (pid {self._process.pid}): stop it first, or wait until it ends")
            self._lines.clear()
            self._done = {}
            self.clock = clock
            command = [sys.executable, "-m", "pbo_runtime.cli", "run", self.file, "--no-live", "--clock", clock,
                       "--duration", "0"]
            self._process = subprocess.Popen(command, cwd=self.folder, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                             stderr=subprocess.STDOUT, text=True, start_new_session=True,
                                             env={**os.environ, "PYTHONUNBUFFERED": "1"})
            self._reader = threading.Thread(target=self._keep_output, args=(self._process,), daemon=True)
            self._reader.start()
        return self.state()

    def _keep_output(self, process: subprocess.Popen[str]) -> None:
        assert process.stdout is not None
        for line in process.stdout:
            self._lines.append(line.rstrip("\n"))
            done = STAGE_DONE.match(line)
            if done:
                self._done[done.group(1)] = int(done.group(2))

    def state(self) -> dict[str, Any]:
        """Whether it runs, its pid and exit status (None while it runs, or never started), the stages each subsystem
        has done, its last lines."""
        process = self._process
        code = None if process is None else process.poll()
        return {"started": process is not None, "running": process is not None and code is None,
                "pid": None if process is None else process.pid, "exit": code, "clock": self.clock,
                "stages_done": dict(self._done), "lines": list(self._lines)}

    def wait(self, timeout: float) -> int | None:
        """The exit status once the run has ended and its output is read; None if it did not end in `timeout` s."""
        process, reader = self._process, self._reader
        if process is None or reader is None:
            return None
        try:
            code = process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            return None
        reader.join()
        return code

    def stop(self) -> bool:
        """SIGINT to the runner (its Ctrl-C: every subsystem stops cleanly); killed after STOP_GRACE. False: none ran."""
        process = self._process
        if process is None or process.poll() is not None:
            return False
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=STOP_GRACE)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        return True
