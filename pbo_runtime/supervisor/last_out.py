"""The last process of a run out removes what the run made, when its supervisor died first.

A supervisor removes its run's objects on every way out but one: SIGKILL. Its children then
stop (`ipc.process.become_child`), and the last of them to end removes the run's shared
memory, semaphores and queues (`cleanup.remove_run`): nothing is left for `pbo clean`.

Who is last is counted by the kernel, not by the processes: each process of the run (the fork
server, the plant, every RTPU) holds a shared flock(2) on the run's table file in /dev/shm from
the moment it joins to its end. One that leaves after the supervisor died drops its share and
waits for the lock exclusively, which it gets only once no process of the run holds a share: it
is then the last one, and removes everything. Two that leave at the same instant both wait; the
one that gets the lock first removes the run, the other finds the table unlinked. The lock
cannot wedge: a process that ends in any way, SIGKILL included, lets go of it with its last
descriptor. A process that joins after the run was removed finds the table unlinked and leaves;
one that joined before is waited for. A child never removes anything while its supervisor
lives: the supervisor removes its run itself.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import signal
import threading
from dataclasses import dataclass

from pbo_runtime.ipc import process, shm
from pbo_runtime.supervisor.cleanup import remove_run

# seconds a leaving process waits to be the last one: the others stop within process.STOP_BOUND
LEAVE_PATIENCE = process.STOP_BOUND + 1.0


@dataclass
class _Share:
    fd: int  # the table file, opened by this process (its own open file description)
    pid: int  # the process that opened it: a forked child inherits the descriptor, not the share
    subsystem: str
    run_id: str


_share: _Share | None = None
_expected: tuple[int, str] | None = None  # (pid, run id) of a process that takes its share on its way out


def join(run_id: str) -> bool:
    """Take this process's share of run `run_id` for its life; False if the run is over (its table is gone).

    A process joins before it makes or opens anything of the run's: the last one out waits for it."""
    global _share
    forget_inherited()
    _share = _open(run_id)
    return _share is not None


def expect(run_id: str) -> None:
    """This process makes nothing of run `run_id` (the fork server): it takes its share only on its way out,
    and may then be the last one out (the table exists before any child starts, or the children are gone)."""
    global _expected
    _expected = (os.getpid(), run_id)


def _open(run_id: str) -> _Share | None:
    table = next((o for o in shm.list_objects() if o.run_id == run_id and o.part == "table" and o.kind == "shm"
                  and o.distrust is None), None)
    if table is None:
        return None
    try:
        fd = os.open(shm.SHM_DIR / table.name.lstrip("/"), os.O_RDONLY | os.O_CLOEXEC | os.O_NOFOLLOW)
    except OSError:
        return None
    fcntl.flock(fd, fcntl.LOCK_SH)  # waits only while a last one out removes the run
    if os.fstat(fd).st_nlink == 0:
        os.close(fd)
        return None
    return _Share(fd, os.getpid(), table.subsystem, run_id)


def forget_inherited() -> None:
    """In a forked child: close the share its parent held (closing it keeps the parent's; unlocking would not)."""
    global _share, _expected
    if _share is not None and _share.pid != os.getpid():
        with contextlib.suppress(OSError):
            os.close(_share.fd)
        _share = None
    if _expected is not None and _expected[0] != os.getpid():
        _expected = None


def leave() -> list[str]:
    """Drop this process's share; the last one out after the supervisor died removes the run. The names removed.

    From then on a stop signal ends the process at once, quietly (it has nothing left to clean);
    once the supervisor is gone, its death said again is ignored."""
    global _share, _expected
    forget_inherited()
    share, _share = _share, None
    expected, _expected = _expected, None
    if share is None and expected is None:
        return []
    process.stopping_done()
    quiet = signal.pthread_sigmask(signal.SIG_BLOCK, (*process.STOP_SIGNALS, signal.SIGALRM))
    gone = False
    try:
        gone = process.supervisor_gone()
        if not gone:
            return []
        if share is None and expected is not None:
            share = _open(expected[1])
            if share is None:
                return []  # removed already, or never made
        assert share is not None
        fcntl.flock(share.fd, fcntl.LOCK_UN)
        if not _lock_alone(share.fd) or os.fstat(share.fd).st_nlink == 0:
            return []  # another process of the run is still in it, or was last and removed it
        return remove_run(share.subsystem, share.run_id).removed
    finally:
        if share is not None:
            os.close(share.fd)
        for signum in process.STOP_SIGNALS:
            signal.signal(signum, _ignored if gone else _ended)
        signal.pthread_sigmask(signal.SIG_SETMASK, quiet)


# Python handlers, not SIG_IGN and SIG_DFL: a signal another thread took just before the switch is
# handled in the main thread after it, and CPython would raise "ignored due to race condition" there.
def _ignored(_signum: int, _frame: object) -> None:
    """The supervisor's death said again: nothing left to do."""


def _ended(signum: int, _frame: object) -> None:
    """End the process by the signal itself, as its default action would."""
    signal.signal(signum, signal.SIG_DFL)
    os.kill(os.getpid(), signum)


def _lock_alone(fd: int) -> bool:
    """Take the lock exclusively (no other process of the run holds a share), waiting at most LEAVE_PATIENCE."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        pass
    taken = threading.Event()

    def take() -> None:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            taken.set()
        except OSError:
            pass

    threading.Thread(target=take, name="last-out", daemon=True).start()
    return taken.wait(LEAVE_PATIENCE)

