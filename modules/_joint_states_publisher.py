"""The JointState publisher of `ros2_joint_states`, in a process of its own so that no DDS work shares the RTPU.

Building a JointState and serializing it is Python work that holds the GIL. In a thread of the
RTPU it took the GIL from the executive's thread at every message, so the releases of every task
on that RTPU waited for it. Here the DDS participant, its writer and the encoding live in a child
process (`python -m modules._joint_states_publisher`) at SCHED_OTHER. The RTPU's cycle fills one
record in a memfd both map (a sequence number, the stamp, then position, velocity and effort),
under a sequence lock: the number is odd while the cycle writes, and the child takes a copy only
when the number was even and the same before and after it. The cycle then adds 1 to an eventfd;
the child wakes, publishes the newest record once, and counts the wakes it folded in as skipped.
Nothing the child does can make the cycle wait.

The child says "ready" (or why it could not start) on a pipe before the task's init returns (a
live spawn's RTPU cycles its other tasks meanwhile), and
ends when the other pipe, whose write end only the RTPU holds, closes: at the task's kill, or when
the RTPU died.
"""

from __future__ import annotations

import contextlib
import json
import mmap
import os
import select
import subprocess
import sys
import time
from typing import Any

import numpy as np

from pbo_runtime import sleep_while_cycling

READY = b"ready"
START_PATIENCE = 60.0  # s the init waits for the child's "ready": importing cyclonedds on a loaded machine
HEADER_WORDS = 2  # the sequence number and the stamp (Unix time, ns), int64 each


def record_bytes(joints: int) -> int:
    return 8 * (HEADER_WORDS + 3 * joints)


class PublisherGone(RuntimeError):
    """The publisher process could not start, or said why."""


class JointStatesPublisher:
    """The task's handle on its publisher process: `begin`, fill `rows` and `stamp`, `send`; `close`."""

    def __init__(self, setup: dict[str, Any], joints: int) -> None:
        self._memfd = os.memfd_create("pbo-joint-states", os.MFD_CLOEXEC)
        os.ftruncate(self._memfd, record_bytes(joints))
        self._shared = mmap.mmap(self._memfd, record_bytes(joints))
        words = np.frombuffer(self._shared, dtype=np.int64, count=HEADER_WORDS)
        self.sequence = words[:1]
        self.stamp = words[1:2]
        self.rows = np.frombuffer(self._shared, dtype=np.float64, offset=8 * HEADER_WORDS).reshape(3, joints)
        self._wake = os.eventfd(0, os.EFD_CLOEXEC)
        hangup_read, self._hangup = os.pipe2(os.O_CLOEXEC)
        ready_read, ready_write = os.pipe2(os.O_CLOEXEC)
        child_fds = (self._memfd, self._wake, hangup_read, ready_write)
        try:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "modules._joint_states_publisher", *map(str, child_fds),
                 json.dumps({**setup, "joints": joints})],
                pass_fds=child_fds, stdin=subprocess.DEVNULL)
        finally:
            os.close(hangup_read)
            os.close(ready_write)
        try:
            said = _read_until_closed(ready_read, START_PATIENCE)
        finally:
            os.close(ready_read)
        if said != READY:
            self.close()
            reason = said.decode(errors="replace").strip() or f"it ended with exit status {self.process.returncode}"
            raise PublisherGone(f"the JointState publisher process did not start: {reason}")

    def begin(self) -> None:
        """Before the record is filled: its sequence number goes odd (the child leaves it alone)."""
        self.sequence[0] += 1

    def send(self) -> None:
        """After: the number goes even again, and the child is woken (one system call, no allocation)."""
        self.sequence[0] += 1
        os.eventfd_write(self._wake, 1)

    def close(self, patience: float = 5.0) -> None:
        """Close the hang-up pipe: the child ends; killed if it does not within `patience`."""
        if self._hangup >= 0:
            os.close(self._hangup)
            self._hangup = -1
        try:
            self.process.wait(timeout=patience)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        os.close(self._wake)
        os.close(self._memfd)


def _read_until_closed(fd: int, patience: float) -> bytes:
    """What the child says before it closes its end (or `patience` runs out). Polled: in a live
    spawn's init the RTPU's other tasks go on cycling meanwhile (`sleep_while_cycling`)."""
    said = b""
    deadline = time.monotonic() + patience
    while time.monotonic() < deadline:
        if not select.select([fd], [], [], 0)[0]:
            sleep_while_cycling(0.005)
            continue
        chunk = os.read(fd, 4096)
        if not chunk:
            break
        said += chunk
    return said


def _serve(memfd: int, wake: int, hangup: int, ready: int, setup: dict[str, Any]) -> None:
    """The child: make the node's writer, say ready, publish the newest record at each wake until the hang-up."""
    with contextlib.suppress(OSError):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))  # (the RTPU's children start there already)
    try:
        from pbo_runtime import ros2_messages

        ros2 = ros2_messages("the ros2_joint_states module")
        from cyclonedds.domain import DomainParticipant
        from cyclonedds.pub import DataWriter
        from cyclonedds.topic import Topic

        participant = DomainParticipant(setup["domain"])
        topic = Topic(participant, ros2.dds_topic(setup["topic"]), ros2.JointState, qos=ros2.ros2_qos())
        writer = DataWriter(participant, topic, qos=ros2.ros2_qos())
        node = ros2.announce_node(participant, setup["node"], writers=[writer])  # noqa: F841 (kept: later nodes get its sample)
    except Exception as exc:
        os.write(ready, f"{type(exc).__name__}: {exc}".encode())
        return
    os.write(ready, READY)
    os.close(ready)
    joints = setup["joints"]
    shared = mmap.mmap(memfd, record_bytes(joints), prot=mmap.PROT_READ)
    record = np.frombuffer(shared, dtype=np.uint8)
    copy = np.zeros_like(record)
    sequence = record[:8].view(np.int64)
    stamp_ns = copy[8:16].view(np.int64)
    rows = copy[8 * HEADER_WORDS:].view(np.float64).reshape(3, joints)
    message = ros2.JointState(header=ros2.Header(frame_id=setup["frame_id"]), name=setup["names"])
    stamp = message.header.stamp
    poller = select.poll()
    poller.register(wake, select.POLLIN)
    poller.register(hangup, select.POLLIN)
    while True:
        woken = dict(poller.poll())
        if hangup in woken:
            return
        os.eventfd_read(wake)
        while True:  # the sequence lock's read: a copy the cycle did not write into meanwhile
            before = int(sequence[0])
            copy[...] = record
            if before % 2 == 0 and before == int(sequence[0]):
                break
            time.sleep(0)
        stamp.sec, stamp.nanosec = divmod(int(stamp_ns[0]), 1_000_000_000)
        message.position, message.velocity, message.effort = rows[0].tolist(), rows[1].tolist(), rows[2].tolist()
        writer.write(message)


if __name__ == "__main__":
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C reaches the RTPU, whose kill hangs up
    memfd, wake, hangup, ready = (int(fd) for fd in sys.argv[1:5])
    _serve(memfd, wake, hangup, ready, json.loads(sys.argv[5]))
