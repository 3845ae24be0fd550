"""A task's figures, typed from the executive to report.json, the summary and the status reply: the
keys users read stay what they were, and what is written reads back the same."""

from __future__ import annotations

import dataclasses
import io
import json
import re

import msgpack
import pytest
from rich.console import Console

from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.errors import InternalError
from pbo_runtime.ipc import messages
from pbo_runtime.ipc.task_statistics import Overrun, TaskStatistics
from pbo_runtime.reports.run_result import PlantFigures, RtpuSettings, RunResult, Stall, SwitchReport, TaskReport
from pbo_runtime.reports.run_summary import print_summary
from pbo_runtime.supervisor.job_control import SwitchRecord
from pbo_runtime.supervisor.status_reply import TaskRow, TaskStatusEntry
from tests.support import DEMO

REPORT_KEYS = [
    "cycles", "overruns", "missed", "errors", "jitter_p50", "jitter_p99", "jitter_max", "exec_p50", "exec_p99",
    "exec_max", "bytes_in", "bytes_out", "bytes_per_cycle", "bytes_moved_per_cycle", "stale_reads",
    "stale_reads_at_switches", "last_stale_read", "cycles_lost_to_switches", "last_cycle_lost", "stable_cycles",
    "expired_reads", "lock_waits_given_up", "dropped_events", "overruns_long_cycle", "overruns_late_release",
    "last_overruns",
]
FIGURES = TaskStatistics(cycles=5001, overruns=3, missed=1, errors=0, jitter_p50=2e-6, jitter_p99=9e-6, jitter_max=3.1e-3,
                         exec_p50=1e-5, exec_p99=2e-5, exec_max=4.2e-3, bytes_in=192, bytes_out=48,
                         bytes_moved_per_cycle=360, stale_reads=4, last_stale_read="in-var 'q_m' 2 ms old",
                         overruns_long_cycle=1, last_overruns=(Overrun(0.25, 3.1e-3, 1e-5), Overrun(1.5, 0.0, 4.2e-3)),
                         outputs=("runs/x/pid_joint.mcap",),
                         devices={"spp0": {"processor": "spp", "routine": "fir", "items": 4, "missed": 0, "service_p50": 2e-5,
                                           "service_p99": 2e-5, "service_max": 2e-5, "calls": 4, "late_calls": 0, "fault": ""}})


def test_a_tasks_figures_keep_the_keys_report_json_always_had():
    assert list(TaskStatistics().to_json()) == REPORT_KEYS  # outputs and devices only when it has some
    assert list(FIGURES.to_json()) == [*REPORT_KEYS, "outputs", "devices"]
    figures = FIGURES.to_json()
    assert (figures["bytes_per_cycle"], figures["overruns_late_release"]) == (240, 2)
    assert figures["last_overruns"] == [[0.25, 3.1e-3, 1e-5], [1.5, 0.0, 4.2e-3]]


@pytest.mark.parametrize("from_table", [False, True], ids=["reported", "from_the_table"])
def test_a_tasks_report_entry_reads_back_as_it_was_written(from_table):
    statistics = TaskStatistics(cycles=7, overruns=1, jitter_max=1e-3, exec_max=2e-3) if from_table else FIGURES
    entry = TaskReport("rtpu0", True, "ON", "", statistics, from_table).to_json()
    assert TaskReport.from_json(entry).to_json() == entry
    assert TaskReport.from_json(entry) == TaskReport("rtpu0", True, "ON", "", statistics, from_table)


def test_a_task_whose_rtpu_was_killed_has_only_its_status_blocks_figures():
    entry = TaskReport("rtpu1", False, "?", "", TaskStatistics(cycles=12), from_table=True).to_json()
    assert list(entry) == ["rtpu", "critical", "state", "error", "from_table", "cycles", "overruns", "missed",
                           "jitter_max", "jitter_p50", "jitter_p99", "exec_p50", "exec_p99", "exec_max", "last_overruns"]
    assert entry["last_overruns"] == [] and entry["from_table"] is True


@pytest.mark.parametrize("settings", [
    {"timer_slack": "1 ns", "cpu": "any", "scheduler": "SCHED_FIFO 50", "spin": "50 µs"},  # the real clock's, in its order
    {"clock": "simulated, 1 ms ticks"},
], ids=["real", "sim"])
def test_an_rtpus_settings_give_report_json_what_the_rtpu_said_in_its_order(settings):
    typed = RtpuSettings.from_json(settings)
    assert json.dumps(typed.to_json()) == json.dumps(settings)
    assert typed.simulated is ("clock" in settings)


def test_the_plants_figures_give_report_json_what_the_plant_host_sent_in_its_order():
    sent = {"steps": 1001, "late": 2, "stalls": 1, "stalled_for": 0.25, "watchdog_trips": 0, "left_fifo_behind": 0.0}
    assert json.dumps(PlantFigures.from_json(sent).to_json()) == json.dumps(sent)
    assert RunResult("s", "c").to_json()["plant"] == {}  # no plant


def test_a_switchs_report_keeps_the_keys_report_json_always_had():
    record = SwitchRecord(3, "pid", "pd", requested_at=1.0, activation=1.002, applied={"rtpu0": (1.002, 1.0025)},
                          first_cycles={"pd": 1.003}, off=["pid"], on=["pd"], lost={"robot": 0}, stale={"robot": 1},
                          lead=0.001, read={"rtpu0": 1.0005}, posted_at=1.0001)
    assert list(record.report().to_json()) == ["sequence", "from", "to", "latency", "skew", "longest", "off", "on",
                                               "cycles_lost", "stale_reads", "lead", "read_delay", "grid_wait", "work",
                                               "posted", "read_delays"]
    changed = dataclasses.replace(record, change="spawn log", restarted=["rtpu1"]).report().to_json()
    assert (changed["change"], changed["restarted"], list(changed)[-2:]) == ("spawn log", ["rtpu1"], ["change", "restarted"])
    assert RunResult("s", "c", switches=[record.report()]).to_json()["switches"] == [record.to_json()]


def test_the_stats_event_carries_the_figures_over_the_wire_as_report_json_has_them():
    wire = msgpack.unpackb(msgpack.packb(messages.event_to_wire("rtpu0", messages.Stats("pid", FIGURES))))
    assert wire == ["stats", "rtpu0", "pid", msgpack.unpackb(msgpack.packb(FIGURES.to_json()))]
    assert messages.event_from_wire(wire) == ("rtpu0", messages.Stats("pid", FIGURES))


@pytest.mark.parametrize("wire", [["stats", "rtpu0", "pid"], ["stats", "rtpu0", "pid", [1, 2]],
                                  ["stats", "rtpu0", "pid", {"cycles": "many"}]], ids=["no_figures", "a_list", "a_word"])
def test_a_malformed_stats_event_is_named_as_our_bug(wire):
    with pytest.raises(InternalError, match="malformed 'stats' event"):
        messages.event_from_wire(wire)


def test_the_status_replys_task_entry_keeps_its_keys_and_reads_back():
    row = TaskRow("pid", "rtpu0", "ON", 1000, 2, 1, 3e-3, 2e-6, 9e-6, 1e-5, 2e-5, 1.1e-5)
    entry = TaskStatusEntry(row, 2, 500.0, None).to_json()
    assert list(entry) == ["task", "rtpu", "state", "cycles", "overruns", "missed", "jitter_max", "jitter_p50",
                           "jitter_p99", "exec_p50", "exec_p99", "exec_last", "index", "rate", "error"]
    assert TaskStatusEntry.from_json(entry) == TaskStatusEntry(row, 2, 500.0, None)


def test_a_status_entry_without_percentiles_reads_back_without_them():
    entry = TaskStatusEntry.from_json({"task": "pid", "rtpu": "rtpu0", "state": "ERROR", "cycles": 300, "rate": 0.0,
                                       "overruns": 2, "jitter_max": 1.5e-3, "exec_last": 3e-5, "error": "singular"})
    assert (entry.row.jitter_p50, entry.row.exec_p99, entry.row.missed, entry.error) == (None, None, 0, "singular")


def summary(result: RunResult) -> str:
    out = io.StringIO()
    print_summary(Console(file=out, width=2000, color_system=None), load_subsystem(DEMO), result, ["a restart"],
                  ["a decision"])
    return out.getvalue()


def test_the_summary_tells_each_task_that_ran_and_what_the_operator_should_know():
    result = RunResult("puma", "joint_pid", duration=5.0, clock="real",
                       tasks={"pid": TaskReport("rtpu0", True, "ON", "", FIGURES),
                              "traj": TaskReport("rtpu0", False, "OFF", "", TaskStatistics()),
                              "robot": TaskReport("rtpu1", True, "?", "", TaskStatistics(cycles=9, overruns=1), True)},
                       stalls=[Stall("robot", "rtpu1", 1.0, None, True)],
                       switches=[SwitchReport(1, "pid", "pd", latency=1e-3, skew=1e-5, longest=2e-4, off=("pid",), on=("pd",),
                                              cycles_lost={"pid": 1}, stale_reads={}, lead=0.0, read_delay=0.0,
                                              grid_wait=0.0, work=0.0, posted=0.0, read_delays={})],
                       realtime={"rtpu0": RtpuSettings(cpu="1", scheduler="SCHED_FIFO 50", timer_slack="1 ns")})
    text = summary(result)
    assert re.search(r"│ pid +│ rtpu0 +│ ON +│ +5001 │ +1000 │ +3 │ +1 │", text)
    assert "│ traj " not in text  # a task that ran no cycle is left out
    assert "overruns of 'pid' (1 ms period): 2 late releases (started up to 3.10 ms late" in text
    assert "it ran SCHED_FIFO already" in text and "1 long cycle (ran up to 4.20 ms" in text
    assert "task 'robot' (rtpu1) finished no cycle from 1.00 s into the run to the stop" in text
    assert "special-purpose processor 'spp0' (task 'pid', routine fir): 4 work items" in text
    assert "switches after which the critical task lost a cycle: 1" in text
    assert "critical task 'robot': 0 cycles lost to switches" in text  # its RTPU never reported: the table's figures
    lines = text.splitlines()
    assert lines.index("a restart") < lines.index("rtpu0: cpu 1, SCHED_FIFO 50, timer slack 1 ns") < lines.index("a decision")
