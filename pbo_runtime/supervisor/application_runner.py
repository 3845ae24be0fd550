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

On `--clock sim` the runner is the application's clock master (`clock.application_lockstep`):
the subsystems take turns, one tick each, in order of simulated time, so the links are read at
the same ticks in every run and the application replays bit for bit. Zenoh links are refused
there: what arrives over a network, and when, is not the simulated clock's to order. With
`--one-process` each subsystem's supervisor hosts its plant and RTPUs (one process a subsystem).
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import posix_ipc

from pbo_runtime.clock.application_lockstep import ApplicationLockstep
from pbo_runtime.config.application import Application
from pbo_runtime.ipc import limits, shm
from pbo_runtime.links.message_link import SYSTEM_MESSAGE_BYTES, MessageLink, message_link_name
from pbo_runtime.links.run_link import RunLink, links_to_json
from pbo_runtime.links.triple_buffer import LinkLayout, TripleBuffer, link_name
from pbo_runtime.links.zenoh_session import link_key
from pbo_runtime.supervisor.cleanup import remove_dead_runs
from pbo_runtime.supervisor.sim_tick import simulation_tick

STOP_GRACE = 15.0  # seconds a subsystem gets to shut down after SIGTERM before it is killed
RELAY_GRACE = 2.0  # seconds to print what an ended subsystem still had in its pipe
TURN_LIMIT = 120.0  # wall seconds a subsystem may hold the simulated clock's turn after its first
CLEANUP_GRACE = 10.0  # seconds a killed subsystem's plant and RTPUs get to end before its objects are removed
EXIT_RUN = 2  # the exit status of a run that failed (a subsystem killed by a signal has none of its own)


class TurnFault(Exception):
    """A subsystem failed (`failed`), or the application was asked to stop, while the subsystems took turns."""

    def __init__(self, reason: str, failed: bool = True) -> None:
        super().__init__(reason)
        self.failed = failed


def unreplayable_links(application: Application) -> str:
    """Why the application cannot run on the simulated clock ("" if it can): its Zenoh links."""
    zenoh = [name for name, link in application.links.items() if link.transport == "zenoh"]
    if not zenoh:
        return ""
    return (f"application '{application.name}': link(s) {', '.join(repr(n) for n in zenoh)} go over Zenoh, whose "
            "deliveries arrive when the network brings them, not at a tick: --clock sim runs an application "
            "that replays bit for bit only over shared memory links; use transport: shm, or --clock real")


def _die_with_parent() -> None:
    """In the child, before exec: SIGTERM when the runner dies, so no subsystem outlives it."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None).prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
        return port


class ApplicationRunner:
    def __init__(self, application: Application, duration: float | None, say: Callable[[str], None],
                 clock: str = "real", out_dir: Path | None = None, fifo: bool | None = None,
                 host: str | None = None, one_process: bool = False, pace: float | None = None) -> None:
        self.application = application
        self.one_process = one_process  # sim: each subsystem's plant and RTPUs in its supervisor's process
        self.pace = pace  # sim: at most this many simulated seconds per wall second, in every subsystem
        self.host = host  # None: every subsystem runs here; else only those placed on this host
        self.local = list(application.subsystems) if host is None else application.on_host(host)
        self.fifo = fifo  # None: each subsystem's default (SCHED_FIFO on the real clock where allowed)
        self.duration = duration
        self.say = say
        self.clock = clock
        self.out_dir = out_dir
        self.run_id = shm.new_run_id()
        self.links: dict[str, RunLink] = {}
        self._links: list[TripleBuffer | MessageLink] = []  # the shm links this runner made and removes
        self._children: dict[str, subprocess.Popen[str]] = {}
        self._terminated: set[str] = set()  # subsystems this runner sent SIGTERM to stop them
        self._relays: list[threading.Thread] = []  # one per subsystem: its output, prefixed, until it ends
        self._stopping = ""
        self.lockstep: ApplicationLockstep | None = None  # on --clock sim: the subsystems' turns
        self._joins: str | None = None  # the folder of the stages' plans and joins, removed at the end

    def run(self) -> int:
        previous = {s: signal.signal(s, self._interrupt) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            removed = remove_dead_runs(self.application.name).removed  # links of a killed runner: same names, same rule
            if removed:
                self.say(f"removed {len(removed)} link(s) left by a dead run: {', '.join(removed)}")
            self._make_links()
            if self.clock == "sim":
                ticks = {key: simulation_tick(self.application.subsystems[key]) for key in self.local}
                self.lockstep = ApplicationLockstep(self.application.name, self.run_id, ticks)
            self._start()
            return self._wait() if self.lockstep is None else self._take_turns(self.lockstep)
        finally:
            self._stop_all()
            if self.lockstep is not None:
                self.lockstep.close()
            for link in self._links:
                link.close()
            if self._joins is not None:
                shutil.rmtree(self._joins, ignore_errors=True)
            for s, handler in previous.items():
                signal.signal(s, handler)

    def _interrupt(self, signum: int, _frame: Any) -> None:
        self._stopping = "Ctrl-C" if signum == signal.SIGINT else "SIGTERM"

    def _make_links(self) -> None:
        for name, spec in self.application.links.items():
            local = [end for end in (spec.sender[0], spec.receiver[0]) if end in self.local]
            if not local:
                continue  # both ends on other hosts: theirs to make
            made = RunLink(spec.kind, spec.transport, spec.dtype, tuple(spec.shape),
                           spec.capacity if spec.kind == "message" else None)
            if spec.transport == "zenoh":  # the sending (periodic) or serving (message) end listens; the other connects
                made = dataclasses.replace(made, key=link_key(self.application.name, name), endpoint=self.endpoint(name))
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
                made = dataclasses.replace(made, shm_name=object_name)
            else:
                object_name = link_name(self.application.name, self.run_id, name)
                self._links.append(TripleBuffer.create(object_name, LinkLayout(np.dtype(spec.dtype), spec.shape)))
                made = dataclasses.replace(made, shm_name=object_name)
            self.links[name] = made
            what = f"messages, {spec.capacity} queued at most" if spec.kind == "message" else "periodic"
            self.say(f"link '{name}': {spec.sender[0]}.{spec.sender[1]} -> {spec.receiver[0]}.{spec.receiver[1]} "
                     f"({spec.dtype} {list(spec.shape)}, {what}, {spec.transport})"
                     + (f": {self.application.listening_subsystem(name)} listens on {made.endpoint}, key {made.key}"
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
        # a replayed run must not depend on string hashing, in the supervisors as in their children
        environment = {**os.environ, "PYTHONHASHSEED": "0"} if self.clock == "sim" else None
        for key in self.local:
            child = subprocess.Popen(self.command(key), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, preexec_fn=_die_with_parent,
                                     start_new_session=True, env=environment)
            self.watch(key, child)

    def watch(self, key: str, child: subprocess.Popen[str]) -> None:
        """Take subsystem `key`'s process: its output is relayed, prefixed with `[key]`, until it ends."""
        self._children[key] = child
        relay = threading.Thread(target=self._relay, args=(key, child), daemon=True)
        relay.start()
        self._relays.append(relay)

    def command(self, key: str) -> list[str]:
        """The `pbo run` that runs subsystem `key` of the application, with the links and the run's options."""
        subsystem = self.application.subsystems[key]
        command = [sys.executable, "-m", "pbo_runtime.cli", "run", subsystem.file, "--no-live", "--clock", self.clock,
                   "--duration", repr(self.duration or 0.0), "--links", links_to_json(self.links)]
        chosen = self.application.run.get(key, {})
        if "config" in chosen:
            command += ["--config", chosen["config"]]
        if "app" in chosen:
            command += ["--app", chosen["app"]]
        if self.out_dir is not None:
            command += ["--out", str(self.out_dir / key)]
        if self.lockstep is not None:
            command += ["--turn", self.lockstep.bases[key]]
        if self.application.stages:
            command += ["--stages", self._stage_plan(key)]
        if self.fifo is not None:
            command.append("--fifo" if self.fifo else "--no-fifo")
        if self.one_process:
            command.append("--one-process")
        if self.pace is not None:
            command += ["--pace", repr(self.pace)]
        return command

    def _stage_plan(self, key: str) -> str:
        """The file of subsystem `key`'s part of the stages, in the folder of the joins (supervisor.stages)."""
        if self._joins is None:
            self._joins = tempfile.mkdtemp(prefix=f"pbo-{self.application.name}-{self.run_id}-")
        # simulated: each goes on a few ticks after the last was done, when every mark is surely there (supervisor.stages)
        lag = 3e-9 * max(self.lockstep.tick_ns.values()) if self.lockstep is not None else 0.0
        plan = {"join": self._joins, "me": key, "everyone": list(self.local), "lag": lag,
                "stages": [stage.get(key) for stage in self.application.stages]}
        path = Path(self._joins) / f"{key}.json"
        path.write_text(json.dumps(plan))
        return str(path)

    def _relay(self, key: str, child: subprocess.Popen[str]) -> None:
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
                return self._worst()  # a fault seen before the stop counts
            if all(code is not None for code in codes.values()):
                return 0
            time.sleep(0.05)

    def _take_turns(self, lockstep: ApplicationLockstep) -> int:
        """The simulated clock: give the subsystems their turns until every one has ended; a failure stops the others."""
        try:
            while lockstep.rotation:
                lockstep.give_turn(lockstep.next_turn(), self._ended_in_turn, self._while_a_turn_lasts)
        except TurnFault as fault:
            self.say(f"stopping every subsystem: {fault}")
            self._stop_all()
            return self._worst() or (EXIT_RUN if fault.failed else 0)  # Ctrl-C: as on the real clock
        return self._worst()

    def _ended_in_turn(self, key: str) -> bool:
        """Whether subsystem `key`, which holds the turn, has ended; TurnFault if it failed."""
        child = self._children[key]
        code = child.poll()
        if code in (None, 0):
            return code == 0
        assert self.lockstep is not None
        how = f"killed by {signal.Signals(-code).name}" if code < 0 else f"exit {code}"
        raise TurnFault(f"subsystem '{key}' (pid {child.pid}) failed ({how}) while it held the simulated clock's "
                        f"turn at {self.lockstep.next_time(key) - self.lockstep.tick_ns[key] / 1e9:.3f} s")

    def _while_a_turn_lasts(self) -> None:
        """While one subsystem has the turn: another that failed, a stop request or a turn held too long ends the run."""
        for key, child in self._children.items():
            code = child.poll()
            if code not in (None, 0):
                how = f"killed by {signal.Signals(-code).name}" if code < 0 else f"exit {code}"
                raise TurnFault(f"subsystem '{key}' (pid {child.pid}) failed ({how}) while waiting for its turn")
        if self._stopping:
            raise TurnFault(self._stopping, failed=False)
        assert self.lockstep is not None
        key = self.lockstep.holding
        # (a first turn holds the subsystem's start too, which its own start-up timeouts watch)
        if key and self.lockstep.turns[key] > 1 and self.lockstep.held_for() > TURN_LIMIT:
            raise TurnFault(f"subsystem '{key}' has held the simulated clock's turn at "
                            f"{self.lockstep.next_time(key) - self.lockstep.tick_ns[key] / 1e9:.3f} s for "
                            f"{self.lockstep.held_for():.0f} s of wall time (its supervisor is stopped or stuck)")

    def _worst(self) -> int:
        """The worst exit status of the subsystems: 0, theirs, or EXIT_RUN for one killed by a signal."""
        codes = [child.returncode for key, child in self._children.items()
                 if child.returncode and not self._stopped_as_asked(key)]
        return max((code if code > 0 else EXIT_RUN) for code in codes) if codes else 0

    def _stopped_as_asked(self, key: str) -> bool:
        """Ended by the SIGTERM this runner sent it: a subsystem in its last moments (its summary printed,
        its interpreter ending) may die of it rather than handle it, and has failed in nothing."""
        return key in self._terminated and self._children[key].returncode == -signal.SIGTERM

    def _stop_all(self) -> None:
        alive = [c for c in self._children.values() if c.poll() is None]
        self._terminated.update(key for key, c in self._children.items() if c in alive)
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
        self._remove_what_killed_subsystems_left()

    def _remove_what_killed_subsystems_left(self) -> None:
        """A subsystem whose supervisor was killed could not remove its table, queues and semaphores: its
        last child out did (`last_out`), and whatever it could not is removed here.

        Its plant and RTPUs end by themselves once their parent is gone (they are told by SIGHUP);
        cleanup leaves a run alone while any of its processes lives, so this waits for them a while.
        """
        for key, child in self._children.items():
            if child.returncode is None or child.returncode >= 0 or self._stopped_as_asked(key):
                continue
            name, ours = self.application.subsystems[key].name, f"{child.pid}-"
            deadline = time.monotonic() + CLEANUP_GRACE
            removed: list[str] = []
            while True:
                cleanup = remove_dead_runs(name)
                removed += cleanup.removed
                if not any(run_id.startswith(ours) for run_id in cleanup.live) or time.monotonic() > deadline:
                    break
                time.sleep(0.1)
            if removed:
                self.say(f"removed {len(removed)} object(s) left by subsystem '{key}' (killed): {', '.join(removed)}")

