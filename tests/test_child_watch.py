"""The supervisor's child watch: a child's exit is told at once, from a pidfd, once per child."""

from __future__ import annotations

import queue
import subprocess
import sys

import pytest

from pbo_runtime.supervisor.child_watch import ChildWatch

pytestmark = [pytest.mark.multiprocess,
              pytest.mark.skipif(not ChildWatch.available(), reason="this Python has no os.pidfd_open")]


def test_each_watched_childs_exit_is_told_once_with_its_role_and_pid():
    told: queue.Queue = queue.Queue()
    watch = ChildWatch(lambda role, pid: told.put((role, pid)))
    quick = subprocess.Popen([sys.executable, "-c", "pass"])
    waiting = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    try:
        assert watch.watch("rtpu0", quick.pid) and watch.watch("rtpu1", waiting.pid)
        assert told.get(timeout=60) == ("rtpu0", quick.pid)  # a net for a hang, not a timing
        assert told.empty()  # the other still lives
        waiting.stdin.close()
        assert told.get(timeout=60) == ("rtpu1", waiting.pid)
    finally:
        watch.close()
        for process in (quick, waiting):
            process.wait()
    assert told.empty()


def test_a_pid_that_is_gone_is_not_watched_and_close_ends_the_thread():
    watch = ChildWatch(lambda role, pid: None)
    finished = subprocess.Popen([sys.executable, "-c", "pass"])
    finished.wait()  # reaped: its pid names no process now
    assert watch.watch("rtpu0", finished.pid) is False  # the supervisor's periodic look remains for it
    watch.close()
    assert not watch._thread.is_alive()
