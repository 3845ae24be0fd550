"""The Supervisor's side of live changes (`pbo spawn/kill/replace/set/app`): what job control asks of it.

How a change reaches the RTPUs: each RTPU loaded the YAML file itself at start, and a live change
must not make it check YAML again (a check takes milliseconds, on the RTPU of a critical task).
So the supervisor writes the checked live description as plain data (`edit.live.to_wire`,
JSON) to `live-N.json` in a 0700 directory of the run, and sends each RTPU a typed `LiveUpdate(N)`
signal; the RTPU reads it between cycles, builds the task specs and the configurations' writers,
stages them and answers `Staged(N)`. Job control then spawns the new tasks and posts a plan; each
executive swaps the staged description in at that plan's cycle boundary. The per-cycle path is
untouched. The directory goes with the run; one a run killed outright left (its name carries the
run id, so its supervisor's pid) is removed by the next run's start.

Where a spawned task's status block comes from: the table is laid out at start with spare blocks
(`table.SPARE_TASK_SLOTS`); `edit.live` gives a new task a free one, and refuses a spawn past them.

An application started live (`pbo app`) runs from the supervisor's watch loop, between commands,
the way `pbo run --app` runs one at start; switches and jobs are refused while it runs.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
import time
from collections.abc import Callable

from pbo_runtime.clock.run_clock import RunClock
from pbo_runtime.config.model import Subsystem, TaskSpec
from pbo_runtime.edit.live import LiveDescription, to_wire
from pbo_runtime.errors import PboError
from pbo_runtime.ipc import messages, shm
from pbo_runtime.supervisor.job_control import JobControl, JobFailure
from pbo_runtime.supervisor.run_report import RunResult
from pbo_runtime.supervisor.stall_watch import StallWatch

STAGE_TIMEOUT = 10.0  # wall seconds for every RTPU to read a live description
LIVE_DIR_PREFIX = "pbo-live-"  # then the run id (supervisor pid - nonce), then mkdtemp's suffix
_LIVE_DIR = re.compile(rf"^{LIVE_DIR_PREFIX}(\d+)-[0-9a-f]+-\w+$")


def remove_dead_live_dirs(root: str | None = None) -> list[str]:
    """Remove the live-description directories of runs whose supervisor is dead (ours only); what went."""
    root = root or tempfile.gettempdir()
    removed: list[str] = []
    try:
        names = os.listdir(root)
    except OSError:
        return removed
    for name in names:
        match = _LIVE_DIR.match(name)
        path = os.path.join(root, name)
        if match is None or shm.pid_alive(int(match.group(1))):
            continue
        try:
            if os.stat(path, follow_symlinks=False).st_uid != os.geteuid() or not os.path.isdir(path):
                continue
        except OSError:
            continue
        shutil.rmtree(path, ignore_errors=True)
        removed.append(path)
    return removed


class LiveChanges:
    """The supervisor's part that stages, adopts and runs live changes; it owns the run's live descriptions."""

    def __init__(self, run_id: str, subsystem: Callable[[], Subsystem], clock: RunClock, signals: dict[str, messages.Queue],
                 result: RunResult, job_control: JobControl, task_states: dict[str, str], every_task: dict[str, TaskSpec],
                 stall_watch: StallWatch, say: Callable[[str], None], while_stepping: Callable[[], None],
                 next_event: Callable[[float, str], tuple[str, messages.Event]],
                 adopted: Callable[[Subsystem], None], set_application: Callable[[str | None], None]) -> None:
        self.run_id = run_id
        self.subsystem = subsystem  # the description the run lives by
        self.clock = clock
        self.signals = signals
        self.result = result
        self.job_control = job_control
        self.task_states = task_states
        self.every_task = every_task  # every task the run has had, by name (the last spec of a name)
        self.stall_watch = stall_watch
        self.say = say
        self.while_stepping = while_stepping
        self.next_event = next_event
        self.adopted = adopted  # the run lives by this description from now on
        self.set_application = set_application  # the application the run is running (None: none)
        self.live: LiveDescription | None = None  # made at start
        self.live_dir = ""
        self.sequence = 0  # the live description staged last (live-N.json)
        self.adopted_sequence = 0  # the one the run lives by (0: the file's)
        self._staged: dict[str, tuple[int, str]] = {}  # rtpu -> (sequence, error) of its last Staged answer
        self.queued_application: str | None = None

    def start(self, slots: int) -> None:
        """Before the RTPUs start: the directory of the run's live descriptions; the description itself."""
        remove_dead_live_dirs()
        self.live_dir = tempfile.mkdtemp(prefix=f"{LIVE_DIR_PREFIX}{self.run_id}-")
        try:
            self.live = LiveDescription.start(self.subsystem(), slots)
        except PboError as exc:  # the run goes on; live changes are refused, saying why
            self.live = None
            self.say(f"live changes are off for this run: {exc}")

    def end(self) -> None:
        if self.live_dir:
            shutil.rmtree(self.live_dir, ignore_errors=True)

    def stage(self, live: LiveDescription) -> None:
        """Every RTPU reads `live` and keeps it for the next plan (see the module's docstring)."""
        self.sequence += 1
        sequence = self.sequence
        path = os.path.join(self.live_dir, f"live-{sequence}.json")
        with open(path + ".tmp", "w", encoding="utf-8") as stream:
            json.dump(to_wire(live.subsystem), stream)
        os.replace(path + ".tmp", path)
        self.every_task.update(live.subsystem.tasks)
        for name in live.subsystem.tasks:
            self.task_states.setdefault(name, "NOT_CREATED")
        for rtpu, queue in self.signals.items():
            queue.signal(messages.LiveUpdate(sequence))
            self.clock.serve(rtpu, self.while_stepping)
        deadline = time.monotonic() + STAGE_TIMEOUT
        while any(self._staged.get(rtpu, (0, ""))[0] != sequence for rtpu in self.signals):
            if self.clock.signals_served_when_sent:
                self.while_stepping()
                if any(self._staged.get(rtpu, (0, ""))[0] != sequence for rtpu in self.signals):
                    raise PboError(f"an RTPU did not read live description {sequence}")
                break
            self.next_event(deadline, f"waiting for the RTPUs to read live description {sequence}")
        errors = [f"{rtpu}: {error}" for rtpu, (seen, error) in self._staged.items() if seen == sequence and error]
        if errors:
            raise PboError(f"the RTPUs could not read the live description: {'; '.join(errors)}")

    def staged(self, rtpu: str, sequence: int, error: str) -> None:
        """An RTPU's `Staged` answer."""
        self._staged[rtpu] = (sequence, error)

    def adopt(self, live: LiveDescription) -> None:
        """The change is applied: `live` describes the running subsystem from now on."""
        self.live = live
        self.adopted_sequence = self.sequence  # (the description staged last: a restart starts from it)
        self.adopted(live.subsystem)
        self.every_task.update(live.subsystem.tasks)
        self.stall_watch.watch_tasks(live.subsystem.tasks.values())

    def run_queued_application(self) -> None:
        """An application started with `pbo app`: its jobs one at a time; a failure ends it, not the run."""
        name, self.queued_application = self.queued_application, None
        if name is None:
            return
        self.set_application(name)
        try:
            self.job_control.run_application(name)
            self.result.jobs_done += self.job_control.jobs_done
            self.say(f"application '{name}' is done")
        except JobFailure as exc:
            self.say(f"application '{name}' stopped: {exc}")
            self.result.faults.append(f"application '{name}' started with pbo app stopped: {exc}")
        finally:
            self.set_application(None)
            self.job_control.job = None
