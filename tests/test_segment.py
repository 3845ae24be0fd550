"""The shared segment with its lock that the state table and the triple buffer are made of."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
import threading

import posix_ipc
import pytest

from pbo_runtime.ipc.segment import LockedSegment, MissingLockError
from pbo_runtime.ipc.shm import pid_alive
from tests.support import unique_name

WORDS = {"holder_word": 1, "recoveries_word": 2}
SAFETY_NET = 60.0  # seconds: a waiter that never takes the lock fails instead of hanging the suite


def dead_pid() -> int:
    """The pid of a process that ran and was reaped."""
    child = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    return int(child.stdout)


def mode_of(path: str) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


@pytest.fixture
def segment(no_leftover_ipc):
    made = LockedSegment.create(unique_name("segment"), 4096, **WORDS)
    yield made
    made.close()


def test_a_segment_and_its_lock_are_created_0600_and_the_creator_removes_both(no_leftover_ipc):
    segment = LockedSegment.create(unique_name("segment"), 4096, **WORDS)
    paths = ("/dev/shm/" + segment.name[1:], "/dev/shm/sem." + segment.lock_name[1:])
    assert [mode_of(path) for path in paths] == [0o600, 0o600]
    assert segment.owner and len(segment.mapping) == 4096 and segment.lock.value == 1
    segment.close()
    assert not any(os.path.exists(path) for path in paths)
    segment.close()  # twice is harmless


def test_a_segment_that_exists_cannot_be_created_again(segment):
    with pytest.raises(posix_ipc.ExistentialError):
        LockedSegment.create(segment.name, 4096, **WORDS)


def test_an_attached_segment_shares_the_memory_and_its_close_leaves_both_names(segment):
    attached = LockedSegment.attach(segment.name, **WORDS)
    attached.mapping[100:103] = b"pbo"
    assert not attached.owner and segment.mapping[100:103] == b"pbo"
    attached.close()
    assert os.path.exists("/dev/shm/" + segment.name[1:]) and os.path.exists("/dev/shm/sem." + segment.lock_name[1:])


def test_a_read_only_attach_reads_but_cannot_write(segment):
    segment.mapping[0:3] = b"abc"
    attached = LockedSegment.attach(segment.name, read_only=True, **WORDS)
    try:
        assert attached.mapping[0:3] == b"abc"
        with pytest.raises(TypeError):
            attached.mapping[0:3] = b"xyz"
    finally:
        attached.close()


def test_attaching_a_missing_segment_raises_existential_error(no_leftover_ipc):
    with pytest.raises(posix_ipc.ExistentialError) as raised:
        LockedSegment.attach(unique_name("segment"), **WORDS)
    assert not isinstance(raised.value, MissingLockError)


def test_attaching_a_segment_without_its_lock_says_the_lock_is_missing(segment):
    posix_ipc.unlink_semaphore(segment.lock_name)
    with pytest.raises(MissingLockError, match=rf"^segment '{segment.name}' has no lock '{segment.name}\.lock'$"):
        LockedSegment.attach(segment.name, **WORDS)


@pytest.mark.parametrize("size", [0, 16])
def test_the_check_sees_the_mapping_even_of_an_empty_segment_and_its_refusal_stands(no_leftover_ipc, size):
    name = unique_name("segment")
    posix_ipc.SharedMemory(name, posix_ipc.O_CREX, mode=0o600, size=size).close_fd()
    seen = []

    def check(mapping) -> None:
        seen.append(len(mapping))
        raise LookupError("not mine")

    try:
        with pytest.raises(LookupError, match=r"^not mine$"):
            LockedSegment.attach(name, check=check, **WORDS)
    finally:
        posix_ipc.unlink_shared_memory(name)
    assert seen == [size]


def test_acquire_signs_the_holder_word_and_release_frees_the_lock(segment):
    segment.acquire()
    assert segment.holder == os.getpid() and segment.lock.value == 0
    segment.release()
    assert segment.lock.value == 1


@pytest.mark.multiprocess
def test_a_lock_whose_holder_died_is_recovered_and_counted(segment):
    gone = dead_pid()
    segment.lock.acquire()
    segment.words[segment.holder_word] = gone
    assert segment.recover_lock_from(gone)
    assert segment.lock.value == 1 and segment.holder == 0 and segment.recoveries == 1


@pytest.mark.multiprocess
def test_a_lock_whose_holder_died_mid_write_is_recovered_without_settling(no_leftover_ipc, monkeypatch):
    # only the holder makes the write sequence odd: an odd one naming the dead process proves it held the lock
    made = LockedSegment.create(unique_name("segment"), 4096, **WORDS, sequence_word=3)
    try:
        gone = dead_pid()
        made.lock.acquire()
        made.words[3] = 2 * gone + 1
        monkeypatch.setattr("pbo_runtime.ipc.segment.time.sleep", lambda _: pytest.fail("settled on a proven holder"))
        assert made.recover_lock_from(gone, settle=3600.0)
        assert made.lock.value == 1 and made.recoveries == 1 and made.words[3] % 2 == 0
    finally:
        made.close()


@pytest.mark.multiprocess
def test_a_lock_another_process_took_since_is_not_taken_away(segment):
    segment.acquire()  # signed by this live process, after the dead one
    try:
        assert not segment.recover_lock_from(dead_pid())
        assert segment.lock.value == 0 and segment.recoveries == 0
    finally:
        segment.release()


@pytest.mark.multiprocess
def test_a_waiter_takes_over_the_lock_of_a_dead_holder(segment):
    segment.lock.acquire()
    segment.words[segment.holder_word] = dead_pid()
    segment.wait_for_lock(0.001)
    assert segment.lock.value == 0 and segment.recoveries == 1
    segment.release()


@pytest.mark.multiprocess
def test_a_zombie_is_dead_and_so_are_pids_that_name_no_process():
    # Regression (issue 17): two liveness checks disagreed on a zombie (dead, not yet reaped),
    # so the lock of a zombie holder was never recovered.
    child = os.fork()
    if child == 0:
        os._exit(0)
    try:
        os.waitid(os.P_PID, child, os.WEXITED | os.WNOWAIT)  # it has died; it stays a zombie until reaped
        assert not pid_alive(child)
    finally:
        os.waitpid(child, 0)
    assert not pid_alive(child) and not pid_alive(0) and not pid_alive(-1)
    assert pid_alive(os.getpid()) and pid_alive(1)


@pytest.mark.multiprocess
def test_a_waiter_takes_over_the_lock_of_a_zombie_holder(segment):
    # Regression (issue 17): the waiter looked at a zombie holder and waited on.
    child = os.fork()
    if child == 0:
        LockedSegment.attach(segment.name, **WORDS).acquire()  # its own mapping, signed with its own pid
        os._exit(0)
    try:
        os.waitid(os.P_PID, child, os.WEXITED | os.WNOWAIT)
        assert segment.holder == child and segment.lock.value == 0
        waiting = threading.Thread(target=segment.wait_for_lock, args=(0.001,), daemon=True)
        waiting.start()
        waiting.join(SAFETY_NET)
        assert not waiting.is_alive() and segment.recoveries == 1
        segment.release()
    finally:
        os.waitpid(child, 0)
