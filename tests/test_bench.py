"""The benchmark command works end to end on tiny counts: every section has its rows, every ratio is a
positive finite number (an overrun-rate ratio may be 0), and the performance page renders. Timing values are never asserted."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

from bench import dora_peer, peers, run_all
from bench._common import machine_info

TINY = {
    "svar_transfer": {"rounds": 1, "iterations": 200, "table_variables": 10},
    "peers": {"iterations": 30, "seconds": 0.2, "warmup": 5, "rounds": 1},
    "scale": {"rounds": 1, "iterations": 50, "rtpu_seconds": 0.03, "table_sizes": (10, 100), "port_counts": (1, 4),
              "task_counts": (1, 3), "rtpu_counts": (1, 2)},
    "realtime": {"seconds": 0.4, "rtpus": (1,), "rounds": 1, "other_seconds": 0.4, "other_rounds": 1},
    "wait": {"seconds": 0.05, "rounds": 1, "loads": (1, 2)},
    "switching": {"switches": 4, "interval": 0.02},
    "verbs": {"window": 0.2, "configs": ("pid_joint",)},
    "helper_threads": {"seconds": 0.1, "rounds": 1, "hogs": 1},
    "check_scale": {"sizes": (12, 30), "repeat": 1},
    "placement": {"tasks": 12, "repeat": 2, "check_repeat": 1},
    "links": {"quick": True, "rounds": 1},
    "dora": {"seconds": 0.3, "rounds": 1, "schedulers": ("other",)},
    "faults": {"cases": ("controller_stop",), "stop_seconds": 0.2, "run_seconds": 1.5},
    "restart": {"kills": 1},
    "data_log": {"seconds": 1.0, "rounds": 1},
    "api_stream": {"seconds": 1.0, "rounds": 1},
    "hmi_latency": {"writes": 10},
    "hmi_load": {"seconds": 4.0, "rounds": 1},
    "sim_speed": {"seconds": 0.2, "rounds": 2, "goal_seconds": 0.2, "goal_runs": 1},
    "startup": {"rounds": 1},
    "robot_limits": {"cycles": 50, "rounds": 1},
    "ros2_bridge": {"seconds": 1.0, "rounds": 1},
}


@pytest.mark.multiprocess
def test_every_benchmark_runs_on_tiny_counts_and_renders_its_tables(tmp_path):
    assert set(TINY) == set(run_all.BENCHMARKS) == set(run_all.QUICK) == set(run_all.FULL)
    plot = tmp_path / "scale.png"
    sections = run_all.collect(TINY, plot_path=str(plot), echo=None)

    assert [s.key for s in sections] == list(run_all.BENCHMARKS)
    for section in sections:
        measured = section.tables or section.notes
        assert measured, f"{section.key}: neither a table nor a note"
        for table in section.tables:
            assert table.rows, f"{section.key}: empty table {table.headers}"
            assert all(len(row) == len(table.headers) for row in table.rows), section.key
        for name, value in section.ratios.items():  # 0 only for a count: an executive without overruns
            assert (value > 0 or "overrun_rate" in name) and value >= 0 and math.isfinite(value), \
                f"{section.key}: {name} = {value}"
        for target in section.targets:
            assert target.value is None or (target.value >= 0 and math.isfinite(target.value)), target.what
        assert section.pace is not None and all(0 < pace < math.inf for pace in section.pace), section.key
    by_key = {s.key: s for s in sections}
    # every peer has its row, measured or reported as not installed / failed, never a crash
    names = [row[0] for row in by_key["peers"].tables[0].rows]
    assert names == [contender.name for contender in peers.CONTENDERS.values()]  # type: ignore[attr-defined]
    assert by_key["svar_transfer"].ratios and by_key["scale"].ratios and by_key["realtime"].tables
    assert plot.stat().st_size > 0

    page = run_all.render(sections, machine_info(), "python -m bench (test)", 1.0)
    assert page.startswith("# Performance\n")
    for heading in ("## Targets", "## Machine", "## How to reproduce", *(f"## {s.title}" for s in sections)):
        assert heading in page
    assert "The machine's pace through the run" in page
    assert all(f"| {s.key} |" in page for s in sections)  # a row of the pace table each


def test_the_overrun_interval_resamples_rounds_so_one_burst_widens_it():
    from bench.realtime import round_bootstrap_interval

    def rounds(pbo: list[int], bare: list[int]) -> list[tuple[dict, dict]]:
        return [({"overruns": p, "cycles": 5000}, {"overruns": b, "cycles": 5000}) for p, b in zip(pbo, bare, strict=True)]

    steady_low, steady_high = round_bootstrap_interval(rounds([10] * 12, [10] * 12))
    assert steady_low == steady_high == 1.0  # every round alike: nothing to resample
    burst_low, burst_high = round_bootstrap_interval(rounds([109] + [1] * 11, [10] * 12))  # the same 120 overruns
    assert burst_low < 0.5 and burst_high > 1.5
    assert round_bootstrap_interval(rounds([0] * 3, [0] * 3)) == (1.0, 1.0)  # none on either side: equal
    assert round_bootstrap_interval(rounds([2], [0])) == (math.inf, math.inf)


@pytest.mark.parametrize("seconds, periods", [(0.00304, 3), (0.00298, 3), (0.0034, 3), (0.0036, 4), (0.0, 0)])
def test_a_hold_after_a_verb_is_measured_in_whole_periods_of_the_held_task(seconds, periods):
    """Two holds of as many cycles, read a few µs apart, are equally long: only a whole period more blames a verb."""
    from bench.verbs import periods_held

    assert periods_held({"task": "robot", "from": 10.0, "to": 10.0 + seconds}, {"robot": 0.001}) == periods
    assert periods_held({"task": "robot", "from": 10.0, "to": 10.0 + 2 * seconds}, {"robot": 0.002}) == periods


def test_an_executive_without_overruns_against_a_bare_loop_with_some_reads_zero_not_n_a():
    from bench.realtime import _overrun_cell, _overrun_ratio

    rounds = [({"overruns": 0, "cycles": 5000}, {"overruns": k, "cycles": 5000}) for k in (0, 2, 1)]
    value, pbo_k, bare_k, interval = _overrun_ratio(rounds)
    assert (value, pbo_k, bare_k) == (0.0, 0, 3)
    assert _overrun_cell(value, pbo_k, bare_k, interval).startswith("0.00x [0.00-")
    assert _overrun_ratio([({"overruns": 2, "cycles": 5000}, {"overruns": 0, "cycles": 5000})])[0] is None
    assert _overrun_cell(None, 0, 0, "[1.00-1.00x]") == "equal (0 and 0)"


@pytest.mark.multiprocess
def test_a_paired_round_runs_the_bare_loops_over_the_seconds_the_run_runs_on_the_rtpus_cpu(monkeypatch):
    import bench.realtime as realtime
    from bench._processes import Workers

    epochs, commands, turned_on = [], [], []
    read_epoch, start_run = realtime.release_epoch, realtime._started_run

    def started_run(*arguments, **options):
        run, on = start_run(*arguments, **options)
        turned_on.append(on)
        return run, on

    monkeypatch.setattr(realtime, "release_epoch", lambda subsystem: epochs.append(read_epoch(subsystem)) or epochs[-1])
    monkeypatch.setattr(realtime, "_started_run", started_run)
    period, seconds = 0.001, 1.0
    with Workers(1, realtime._bare_main, (period, False), what="bare loop") as workers:
        send_each = workers.send_each
        workers.send_each = lambda sent: commands.extend(sent) or send_each(sent)  # type: ignore[method-assign]
        report, records = realtime.paired_round(workers, realtime.config_path(1), 1, period, seconds, fifo=False,
                                                round_index=1)

    (task,) = report["tasks"].values()
    (record,) = records
    ((first_release, end, cpu),) = commands
    (on,) = turned_on
    assert report["stopped_by"] == "duration" and task["cycles"] > 0
    # from the first release of RTPU 0 10 ms after the run said its configuration is on, plus half a period, to its end
    assert end == on + seconds
    assert 0.5 * period - 1e-9 <= first_release - (on + 0.01) < 1.5 * period + 1e-9
    # a cycle per release before the end, at most: one at least, fewer where a loaded machine skipped releases
    assert len(record["jitter"]) == len(record["spanned"])
    assert 1 <= len(record["jitter"]) <= math.ceil((end - first_release) / period)
    # on the RTPU's CPU (turned by one in round 1), half a period after a release of the RTPU
    cpus = sorted(os.sched_getaffinity(0))
    assert cpu == cpus[1 % len(cpus)]
    assert report["realtime"]["rtpu0"]["cpu"] == str(cpu)
    (epoch,) = epochs
    periods = (first_release - epoch) / period
    assert abs(periods % 1.0 - 0.5) < 1e-3  # k + 0.5 periods (round() would take k + 0.5 to the even side)


def test_bare_loops_are_released_midway_between_the_releases_of_the_rtpus_on_their_cpu():
    from bench.realtime import bare_phases, placement
    from pbo_runtime.clock.clocks import release_stagger

    period = 0.001
    for n_cpus in (1, 2, 4):
        for n in (1, 2, 3, 4):
            for round_index in range(3):
                where = placement(n, list(range(n_cpus)), round_index)
                stagger = release_stagger(period, n)
                for cpu in set(where):
                    rtpus = sorted(i * stagger for i in range(n) if where[i] == cpu)
                    bares = [phase % period for phase, c in zip(bare_phases(where, period), where, strict=True) if c == cpu]
                    for bare in bares:  # midway between the RTPU releases around it, on its CPU
                        before = max((r for r in rtpus if r <= bare), default=rtpus[-1] - period)
                        after = min((r for r in rtpus if r > bare), default=rtpus[0] + period)
                        assert bare - before == pytest.approx(after - bare), (n_cpus, n, bare, rtpus)
                    releases = sorted(rtpus + bares)
                    assert min(np.diff([*releases, releases[0] + period])) > 0.1 * period  # none spins with another


def test_every_rtpu_visits_every_cpu_as_the_rounds_turn():
    from bench.realtime import placement

    cpus = [0, 1]
    for n in (1, 2, 4):
        seen = [{placement(n, cpus, r)[i] for r in range(len(cpus))} for i in range(n)]
        assert all(visited == set(cpus) for visited in seen)


@pytest.mark.multiprocess
def test_a_run_that_never_turns_its_configuration_on_is_reported_with_its_last_words(tmp_path):
    from bench.realtime import _started_run

    broken = tmp_path / "broken.yaml"
    broken.write_text("subsystem: broken\nrtpus: [rtpu0]\nvariables: {}\ntasks: {}\nconfigurations: {none: [ghost]}\n")
    with pytest.raises(RuntimeError, match=r"did not turn its configuration on \(exit 1\)"):
        _started_run(broken, 1.0, False, tmp_path / "report.json")  # a file with errors: not tried again


class FailingBareLoopsFake:
    """Fake bare loops for one test: they take the round's commands and never report."""

    def send_each(self, commands):
        self.commands = commands

    def answers(self, timeout):
        raise RuntimeError("1 of 1 bare loop processes did not report")


@pytest.mark.multiprocess
def test_a_round_whose_bare_loops_fail_stops_its_run_and_leaves_no_shared_memory():
    from bench.realtime import config_path, paired_round

    def objects_of_the_run() -> set[str]:
        found = set()
        for folder in ("/dev/shm", "/dev/mqueue"):
            if os.path.isdir(folder):
                found |= {entry for entry in os.listdir(folder) if entry.startswith("pbo.bench_rt1.")}
        return found

    before = objects_of_the_run()
    loops = FailingBareLoopsFake()
    with pytest.raises(RuntimeError, match="did not report"):
        paired_round(loops, config_path(1), 1, 0.001, 60.0, fifo=False)  # type: ignore[arg-type]
    assert len(loops.commands) == 1
    assert objects_of_the_run() - before == set()


def _dora_processes() -> list[str]:
    """Command lines of live processes of a dora benchmark run (its work folder is in their arguments)."""
    found = []
    for entry in os.listdir("/proc"):
        try:
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                command = f.read().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if "pbo-bench-dora-" in command:
            found.append(command)
    return found


def _bench_shared_memory() -> set[str]:
    """Benchmark segments in /dev/shm whose maker is gone (a live benchmark elsewhere on the machine owns its own)."""
    orphans = set(dora_peer.orphan_segments())
    for entry in os.listdir("/dev/shm"):
        if entry.removeprefix("sem.").startswith("pbo.bench."):
            maker = entry.removeprefix("sem.").removeprefix("pbo.bench.").split("-", 1)[0]
            if not (maker.isdigit() and os.path.exists(f"/proc/{maker}")):
                orphans.add(entry)
    return orphans


DORA_MISSING = dora_peer.missing()


def test_the_dora_benchmark_is_skipped_with_its_reason_when_dora_is_not_installed(monkeypatch):
    import importlib.util

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *rest: None if name == "dora" else find_spec(name, *rest))
    assert dora_peer.dora_command() is None
    section = dora_peer.run(seconds=0.1, rounds=1)
    assert not section.tables and not section.ratios and not section.targets
    assert "not installed" in section.text() and "pip install" in section.text()


@pytest.mark.multiprocess
@pytest.mark.skipif(bool(DORA_MISSING), reason=DORA_MISSING)
def test_a_tiny_dora_run_measures_every_way_and_leaves_no_process_or_shared_memory():
    scheduler = "fifo" if dora_peer.fifo_permitted() else "other"  # fifo: every process of both sides at an RTPU's priority
    before = _bench_shared_memory()
    section = dora_peer.run(seconds=0.3, rounds=1, schedulers=(scheduler,))

    (table,) = section.tables
    assert [row[:2] for row in table.rows] == [[scheduler, dora_peer.LABELS[peer]] for peer in dora_peer.PEERS]
    assert not any("failed" in cell for row in table.rows for cell in row), table.rows
    assert set(section.ratios) == {f"{peer} / dora-rs one-way {q} ({scheduler})" for peer in ("triple buffer", "zenoh")
                                   for q in ("p50", "p99")}
    assert _dora_processes() == []
    assert _bench_shared_memory() - before == set()


@pytest.mark.multiprocess
@pytest.mark.skipif(bool(DORA_MISSING), reason=DORA_MISSING)
def test_a_dora_run_that_does_not_finish_in_time_is_stopped_with_all_its_nodes_and_their_shared_memory():
    before = _bench_shared_memory()
    with pytest.raises(RuntimeError, match="did not finish within"):
        dora_peer.dora_round(5.0, patience=-3.5)  # given 1.5 s for a 5 s run
    assert _dora_processes() == []
    assert _bench_shared_memory() - before == set()


@pytest.mark.skipif(bool(DORA_MISSING), reason=DORA_MISSING)
def test_without_the_right_to_sched_fifo_the_fifo_rows_are_left_out_with_the_reason(monkeypatch):
    monkeypatch.setattr(dora_peer, "fifo_permitted", lambda: False)
    section = dora_peer.run(seconds=0.1, rounds=1, schedulers=("fifo",))
    assert not section.tables and not section.ratios
    assert "fifo: not measured" in section.text() and "ulimit -r" in section.text()


def test_a_hold_is_the_machines_when_it_overlaps_a_gap_of_a_real_time_probe_and_never_when_the_probe_was_not():
    from bench.platform_probe import WAKE_EVERY, Gap, Gaps

    gaps = Gaps([Gap(0, 10.0, 0.002), Gap(1, 10.001, 0.006), Gap(1, 20.0, 0.001)], realtime=True)
    assert gaps.during(10.005, 10.006) == Gap(1, 10.001, 0.006)  # the longer of two that overlap
    assert gaps.during(10.0075 + WAKE_EVERY, 10.02) is None  # after the gap (and the probe's sleep) ended
    assert gaps.during(9.0, 9.999) is None
    assert Gaps(gaps.gaps, realtime=False).during(10.005, 10.006) is None  # a SCHED_OTHER probe proves nothing


@pytest.mark.multiprocess
def test_the_platform_probe_runs_one_process_per_cpu_and_reports_what_it_was_granted():
    import time

    from bench.platform_probe import PlatformProbe

    with PlatformProbe() as probe:
        time.sleep(0.2)
    assert len(probe.processes) == len(os.sched_getaffinity(0))
    assert all(p.returncode == 0 for p in probe.processes)
    assert all(g.cpu in os.sched_getaffinity(0) and g.length > 0 for g in probe.gaps.gaps)
    assert probe.gaps.realtime == (os.sched_getscheduler(0) is not None and _fifo_allowed())
    assert probe.gaps.summary().startswith(f"{len(probe.gaps.gaps)} gaps over" if probe.gaps.gaps else "no gap over")


def _fifo_allowed() -> bool:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    except OSError:
        return False
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return True
