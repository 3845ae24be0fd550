"""The periodic link's receiving module (TR §5.2): what it writes and the counts it publishes.

A real triple buffer and a real table; the task runs in this process, its cycles called by hand.
"""

from __future__ import annotations

import numpy as np
import pytest

from modules.link_receiver import LinkReceiver
from pbo_runtime.links.triple_buffer import LinkLayout, TripleBuffer
from tests.support import make_task, unique_name, variables


@pytest.fixture
def receiver(make_table):
    link = TripleBuffer.create(unique_name("tb-q"), LinkLayout(np.dtype("float64"), (3,)), role="sender")
    table = make_table(variables(("q_d", "float64", (3,)), ("link_counts", "float64", (3,))))
    spec = {"kind": "periodic", "transport": "shm", "object": link.name, "dtype": "float64", "shape": [3]}
    task = make_task(table, LinkReceiver, "follow", {"value": ("q_d", (3,)), "counts": ("link_counts", (3,))},
                     {"goal": spec})
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0), task.last_error
    yield link, table, task
    task.kill()
    link.close()


def test_the_newest_item_is_written_with_its_age_by_the_senders_stamp(receiver):
    link, table, task = receiver
    link.write(np.array([0.1, 0.2, 0.3]), stamp_ns=9_996_000_000)
    task.run_cycle(10.0)
    np.testing.assert_array_equal(table.read("q_d")[0], [0.1, 0.2, 0.3])
    lost, reused, age = table.read("link_counts")[0]
    assert (lost, reused) == (0, 0) and age == pytest.approx(0.004)


def test_an_item_stamped_after_the_readers_release_reads_as_age_zero(receiver):
    # Regression (seen once in CI, the leader/follower application): the sender published between
    # the reader's release and its read, and the age by the release came out -3.2 µs.
    link, table, task = receiver
    link.write(np.array([0.1, 0.2, 0.3]), stamp_ns=10_000_003_176)
    task.run_cycle(10.0)
    assert table.read("link_counts")[0][2] == 0.0
