"""An RTPU's real-time settings are asked for and reported, never assumed (run in a child process)."""

from __future__ import annotations

import json
import subprocess
import sys

from tests.conftest import REPO

APPLY = "import json, sys; from rtpu import _realtime; print(json.dumps(_realtime.apply({cpu}, {fifo})))"


def applied(cpu, fifo: bool) -> dict:
    done = subprocess.run([sys.executable, "-c", APPLY.format(cpu=cpu, fifo=fifo)], capture_output=True, text=True,
                          cwd=REPO, timeout=60)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_an_rtpu_is_pinned_to_the_cpu_its_yaml_names():
    assert applied(0, False) == {"timer_slack": "1 ns", "cpu": "0", "scheduler": "SCHED_OTHER"}


def test_a_cpu_the_machine_does_not_have_is_reported_not_fatal():
    assert applied(4096, False)["cpu"].startswith("not pinned: CPU 4096: ")


def test_sched_fifo_is_reported_as_granted_or_refused_with_the_reason():
    scheduler = applied(None, True)["scheduler"]
    assert scheduler == "SCHED_FIFO 50" or scheduler.startswith("SCHED_OTHER: SCHED_FIFO refused (")
