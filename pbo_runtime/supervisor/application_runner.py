"""`pbo run APP.yaml`: start every subsystem of an application, join them by links, stop them together.

Each subsystem runs as its own `pbo run` (its own supervisor, table, RTPUs and plant), started
by this runner with `--links`, the JSON that tells its tasks where each link is. The runner
makes the links first (shared memory: a triple buffer per periodic link, a message queue per
message link, 0600, named after the runner's run) and removes them last, whatever happened.
`run:` in the application file picks a subsystem's configuration (`--config`) or application of
jobs (`--app`); an inline subsystem is run by its `app.yaml#key` reference. Each subsystem's output is shown line by line
with its name in front. When one subsystem fails, or on Ctrl-C, the others are stopped
(SIGTERM: their supervisors shut down cleanly); the exit status is the worst of theirs.

On two machines (`hosts:` in the file, `pbo run APP --host NAME` on each), a runner starts only
its host's subsystems, makes only the shm links both of whose ends are local, and hands its
zenoh ends an endpoint and a key that follow from the file alone (the listening end's host
address and the link's port; `pbo/<application>/<link>`), so two runners that never talk to each
other agree. Without `--host`, every host is this machine: zenoh links listen on loopback.
"""

from __future__ import annotations

import ctypes
import json
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import posix_ipc

from pbo_runtime.ipc import limits
from pbo_runtime.ipc import shm
from pbo_runtime.config.application import Application
from pbo_runtime.links.zenoh_link import link_key
from pbo_runtime.supervisor.cleanup import remove_dead_runs
from pbo_runtime.links.message_link import SYSTEM_MESSAGE_BYTES, MessageLink, message_link_name
from pbo_runtime.links.triple_buffer import LinkLayout, TripleBuffer, link_name

STOP_GRACE = 15.0  # seconds a subsystem gets to shut down after SIGTERM before it is killed
RELAY_GRACE = 2.0  # seconds to print what an ended subsystem still had in its pipe


def _die_with_parent() -> None:
    """In the child, before exec: SIGTERM when the runner dies, so no subsystem outlives it."""
    try:
        ctypes.CDLL(None).prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


class ApplicationRunner:
    def __init__(self, application: Application, duration: float | None, say: Callable[[str], None],
                 clock: str = "real", out_dir: Path | None = None, fifo: bool | None = None,
                 host: str | None = None) -> None:
        self.application = application
        self.host = host  # None: every subsystem runs here; else only those placed on this host
        self.local = list(application.subsystems) if host is None else application.on_host(host)
        self.fifo = fifo  # None: each subsystem's default (SCHED_FIFO on the real clock where allowed)
        self.duration = duration
        self.say = say
        self.clock = clock
        self.out_dir = out_dir
        self.run_id = shm.new_run_id()
        self.links: dict[str, dict[str, Any]] = {}
        self._links: list[TripleBuffer | MessageLink] = []  # the shm links this runner made and removes
        self._children: dict[str, subprocess.Popen] = {}
        self._relays: list[threading.Thread] = []  # one per subsystem: its output, prefixed, until it ends
        self._stopping = ""

    def run(self) -> int:
        previous = {s: signal.signal(s, self._interrupt) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            removed = remove_dead_runs(self.application.name).removed  # links of a killed runner: same names, same rule
            if removed:
                self.say(f"removed {len(removed)} link(s) left by a dead run: {', '.join(removed)}")
            self._make_links()
            self._start()
            return self._wait()
        finally:
            self._stop_all()
            for link in self._links:
                link.close()
            for s, handler in previous.items():
                signal.signal(s, handler)

    def _interrupt(self, signum: int, _frame: Any) -> None:
        self._stopping = "Ctrl-C" if signum == signal.SIGINT else "SIGTERM"

    def _make_links(self) -> None:
        for name, spec in self.application.links.items():
            local = [end for end in (spec.sender[0], spec.receiver[0]) if end in self.local]
            if not local:
                continue  # both ends on other hosts: theirs to make
            entry: dict[str, Any] = {"kind": spec.kind, "transport": spec.transport, "dtype": spec.dtype,
                                     "shape": list(spec.shape)}
            if spec.kind == "message":
                entry["capacity"] = spec.capacity
            if spec.transport == "zenoh":  # the sending (periodic) or serving (message) end listens; the other connects
                entry["key"] = link_key(self.application.name, name)
                entry["endpoint"] = self.endpoint(name)
            elif spec.kind == "message":
                object_name = message_link_name(self.application.name, self.run_id, name)
                try:
                    self._links.append(MessageLink.create(object_name, spec.capacity))
                except (OSError, posix_ipc.Error) as exc:
                    size = limits.QueueSize(object_name, spec.capacity, SYSTEM_MESSAGE_BYTES)
                    error = limits.explain(exc, f"creating message link '{name}' ({object_name})", [size])
                    if error is None:
                        raise
                    raise error from None
                entry["object"] = object_name
            else:
                object_name = link_name(self.application.name, self.run_id, name)
                self._links.append(TripleBuffer.create(object_name, LinkLayout(np.dtype(spec.dtype), spec.shape)))
                entry["object"] = object_name
            self.links[name] = entry
            what = f"messages, {spec.capacity} queued at most" if spec.kind == "message" else "periodic"
            self.say(f"link '{name}': {spec.sender[0]}.{spec.sender[1]} -> {spec.receiver[0]}.{spec.receiver[1]} "
                     f"({spec.dtype} {list(spec.shape)}, {what}, {spec.transport})"
                     + (f": {self.application.listening_subsystem(name)} listens on {entry['endpoint']}, key {entry['key']}"
                        if self.host is not None and spec.transport == "zenoh" else ""))

    def endpoint(self, link: str) -> str:
        """Where zenoh link `link`'s listening end listens: the file's endpoint; on a host, its address and the
        link's port; with every host here, loopback (the link's port if written, else a free one)."""
        spec = self.application.links[link]
        if spec.endpoint:
            return spec.endpoint
        if self.host is not None:
            listening = self.application.placement[self.application.listening_subsystem(link)]
            return f"tcp/{self.application.hosts[listening]}:{spec.port}"
        return f"tcp/127.0.0.1:{spec.port if spec.port_given else _free_port()}"

    def _start(self) -> None:
        for key in self.local:
            child = subprocess.Popen(self.command(key), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, preexec_fn=_die_with_parent, start_new_session=True)
            self.watch(key, child)

    def watch(self, key: str, child: subprocess.Popen) -> None:
        """Take subsystem `key`'s process: its output is relayed, prefixed with `[key]`, until it ends."""
        self._children[key] = child
        relay = threading.Thread(target=self._relay, args=(key, child), daemon=True)
        relay.start()
        self._relays.append(relay)

    def command(self, key: str) -> list[str]:
        """The `pbo run` that runs subsystem `key` of the application, with the links and the run's options."""
        subsystem = self.application.subsystems[key]
        command = [sys.executable, "-m", "pbo_runtime.cli", "run", subsystem.file, "--no-live", "--clock", self.clock,
                   "--duration", repr(self.duration or 0.0), "--links", json.dumps(self.links)]
        chosen = self.application.run.get(key, {})
        if "config" in chosen:
            command += ["--config", chosen["config"]]
        if "app" in chosen:
            command += ["--app", chosen["app"]]
        if self.out_dir is not None:
            command += ["--out", str(self.out_dir / key)]
        if self.fifo is not None:
            command.append("--fifo" if self.fifo else "--no-fifo")
        return command

    def _relay(self, key: str, child: subprocess.Popen) -> None:
        assert child.stdout is not None
        for line in child.stdout:
            sys.stdout.write(f"[{key}] {line}")
            sys.stdout.flush()

    def _wait(self) -> int:
        """Until every subsystem ends; the first failure or a stop request stops the others."""
        while True:
            codes = {key: child.poll() for key, child in self._children.items()}
            failed = [key for key, code in codes.items() if code not in (None, 0)]
            if failed or self._stopping:
                reason = f"subsystem '{failed[0]}' failed (exit {codes[failed[0]]})" if failed else self._stopping
                self.say(f"stopping every subsystem: {reason}")
                self._stop_all()
                return max((c.returncode or 0) for c in self._children.values())  # a fault seen before the stop counts
            if all(code is not None for code in codes.values()):
                return 0
            time.sleep(0.05)

    def _stop_all(self) -> None:
        alive = [c for c in self._children.values() if c.poll() is None]
        for child in alive:
            child.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + STOP_GRACE
        for child in alive:
            try:
                child.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait()
        for relay in self._relays:  # a subsystem's last lines (its summary) are printed before the runner's
            relay.join(timeout=RELAY_GRACE)

