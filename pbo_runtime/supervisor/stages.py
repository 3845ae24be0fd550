"""A subsystem's part of an application's stages (`run:` with `parallel:`, config.parallel), and the joins.

The application's runner hands each subsystem a plan (`pbo run --stages PLAN`): its steps or
application in each stage (none where the stage does not name it), the folder of the joins, and
every subsystem's name. After each stage a subsystem leaves a mark in that folder, with the
time it was done, and goes on once every subsystem has left its own: the join. On the simulated
clock it goes on at its first tick at least `lag` (a few ticks, the plan's) after the last of
them was done: the subsystems take their turns in order of simulated time, so by then every
mark made before is there to be read, and the join falls on the same tick in every run.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pbo_runtime.config.parallel import stage_application
from pbo_runtime.edit.live import LiveDescription
from pbo_runtime.supervisor.job_control import POLL, JobControl


def run_stages(control: JobControl, plan_file: str, say: Callable[[str], None]) -> list[str]:
    """Run this subsystem's part of each stage, joining the others after each; the jobs it ran, in order."""
    plan: dict[str, Any] = json.loads(Path(plan_file).read_text())
    join, me, everyone, lag = Path(plan["join"]), str(plan["me"]), list(plan["everyone"]), float(plan["lag"])
    done: list[str] = []
    for number, stage in enumerate(plan["stages"], 1):
        if stage is not None:
            if "app" in stage:
                control.run_application(stage["app"])
            else:
                base = control.subsystem
                live = LiveDescription.start(base, len(base.tasks))  # one more application, nothing else
                control.subsystem = live.with_application(stage_application(number), stage["steps"]).subsystem
                try:
                    control.run_application(stage_application(number))
                finally:
                    control.subsystem = base
            done.extend(control.jobs_done)
        host = control.host
        finished = join / f"{number}.{me}"
        finished.with_suffix(".new").write_text(repr(host.now()))
        os.replace(finished.with_suffix(".new"), finished)  # read whole or not at all
        control.mark(host.now(), "job", f"stage {number} done")
        say(f"stage {number} done here; joining {', '.join(everyone)}")
        control.path = [f"stage {number}", "join"]
        while not _joined(join, number, everyone, host.now(), lag):
            host.pump(host.tick or POLL)
        control.path = []
        control.mark(host.now(), "job", f"stage {number} joined")
    return done


def _joined(join: Path, number: int, everyone: list[str], now: float, lag: float) -> bool:
    """Every subsystem left its mark of stage `number`, the last at least `lag` ago."""
    marks = [join / f"{number}.{key}" for key in everyone]
    if not all(mark.exists() for mark in marks):
        return False
    return now >= max(float(mark.read_text()) for mark in marks) + lag - 1e-9
