"""The periodic link's receiving module (TR §5.2): what it writes and the counts it publishes.

A real triple buffer and a real table; the task runs in this process, its cycles called by hand.
"""

from __future__ import annotations

import numpy as np
import pytest

from modules.link_receiver import LinkReceiver
from pbo_runtime import Status
from pbo_runtime.errors import ParamError
from pbo_runtime.links.run_link import RunLink
from pbo_runtime.links.triple_buffer import LinkLayout, TripleBuffer
from tests.support import make_task, unique_name, variables


@pytest.fixture
def receiver(make_table):
    link = TripleBuffer.create(unique_name("tb-q"), LinkLayout(np.dtype("float64"), (3,)), role="sender")
    table = make_table(variables(("q_d", "float64", (3,)), ("link_counts", "float64", (3,))))
    spec = RunLink("periodic", "shm", "float64", (3,), shm_name=link.name)
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


@pytest.fixture
def bounded_receiver(make_table):
    """A receiver with fresh_within: 0.1 s, on a shm link whose sender the test drives."""
    link = TripleBuffer.create(unique_name("tb-f"), LinkLayout(np.dtype("float64"), (3,)), role="sender")
    table = make_table(variables(("q_d", "float64", (3,)), ("link_counts", "float64", (3,))))
    spec = RunLink("periodic", "shm", "float64", (3,), shm_name=link.name)
    task = make_task(table, LinkReceiver, "follow", {"value": ("q_d", (3,)), "counts": ("link_counts", (3,))},
                     {"goal": spec}, params={"link": "goal", "fresh_within": 0.1})
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0), task.last_error
    yield link, table, task
    task.kill()
    link.close()


def test_a_bounded_receiver_says_stable_until_the_first_item_then_continues(bounded_receiver):
    link, _table, task = bounded_receiver
    assert task.run_cycle(10.0) is Status.STABLE  # nothing came yet: the critical tasks hold
    link.write(np.array([0.1, 0.2, 0.3]), stamp_ns=10_000_000_000)
    assert task.run_cycle(10.01) is Status.CONTINUE


@pytest.mark.parametrize("last_cycle, status", [(10.1, Status.CONTINUE), (10.11, Status.STABLE)],
                         ids=["at its bound", "past its bound"])
def test_a_bounded_receiver_is_stale_past_its_bound_without_a_new_item_judged_on_its_own_clock(bounded_receiver, last_cycle,
                                                                                              status):
    link, table, task = bounded_receiver
    link.write(np.array([0.1, 0.2, 0.3]), stamp_ns=999_000_000_000)  # the stamp plays no part: only arrivals count
    assert task.run_cycle(10.0) is Status.CONTINUE
    assert task.run_cycle(10.05) is Status.CONTINUE  # the same item again: not new, but within the bound
    assert task.run_cycle(last_cycle) is status
    np.testing.assert_array_equal(table.read("q_d")[0], [0.1, 0.2, 0.3])  # the last item stays written


def test_a_bounded_receiver_resumes_by_itself_at_the_next_item(bounded_receiver):
    link, table, task = bounded_receiver
    link.write(np.array([0.1, 0.2, 0.3]))
    task.run_cycle(10.0)
    assert task.run_cycle(10.5) is Status.STABLE
    link.write(np.array([0.4, 0.5, 0.6]))
    assert task.run_cycle(10.502) is Status.CONTINUE
    np.testing.assert_array_equal(table.read("q_d")[0], [0.4, 0.5, 0.6])


@pytest.mark.parametrize("bound, wanted", [
    (-0.1, r"fresh_within must be in \[0, 3600\], got: -0\.1"),
    (float("nan"), r"fresh_within must be in \[0, 3600\], got: \.nan"),
    (1e300, r"fresh_within must be in \[0, 3600\], got: 1e\+300"),
    ("50 ms", "fresh_within must be a number"),
])
def test_a_receivers_bound_must_be_seconds_not_below_zero(bound, wanted):
    with pytest.raises(ParamError, match=wanted):
        LinkReceiver.build_params({"link": "goal", "fresh_within": bound})
