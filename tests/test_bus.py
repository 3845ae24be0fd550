"""Bus utilisation (TR eq. 1-2, §4.5): every number here is worked out by hand first."""

from __future__ import annotations

import csv
import dataclasses
import io
import json
from pathlib import Path

import pytest
from rich.console import Console

from pbo_runtime.analysis import bus as _bus
from pbo_runtime.config import bus_model
from pbo_runtime.config.bus_model import BusModelError
from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.config.model import BusSpec, ConfigurationSpec, PortBinding, RtpuSpec, Subsystem, TaskSpec, VariableSpec
from pbo_runtime.objects.ports import PortKind, PortSpec

REPO = Path(__file__).resolve().parent.parent
DEMO = REPO / "configs" / "pid_joint.yaml"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@dataclasses.dataclass(frozen=True)
class _AperiodicTask(TaskSpec):
    """A TaskSpec with the aperiodic fields, whether or not TaskSpec has them yet."""

    aperiodic: bool = True
    min_interarrival: float | None = None


def bind(kind: str, variable: str, shape: tuple[int, ...], dtype: str = "float64") -> PortBinding:
    return PortBinding(PortSpec(variable, PortKind(kind), variable, dtype, shape), variable, shape)


def subsystem(variables: dict[str, tuple[str, tuple[int, ...]]], tasks: list[TaskSpec],
              configurations: dict[str, list[str]], bandwidth: float = 1e6, delta: float = 8.0) -> Subsystem:
    return Subsystem(
        name="hand", file="<hand>", rtpus=(RtpuSpec("rtpu0", 0), RtpuSpec("rtpu1", 1)),
        bus=BusSpec(bandwidth=bandwidth, lock_overhead=delta), plant=None, devices={}, dims={},
        variables={n: VariableSpec(n, i, dt, sh) for i, (n, (dt, sh)) in enumerate(variables.items())},
        tasks={t.name: dataclasses.replace(t, index=i) for i, t in enumerate(tasks)},
        configurations={n: ConfigurationSpec(n, tuple(ts)) for n, ts in configurations.items()},
        jobs={}, applications={}, init_order=tuple(t.name for t in tasks),
    )


# a: 3 float64 = 24 B; b: 4 float32 = 16 B; c: one int32 = 4 B; k: 10 float64 = 80 B (a const)
SMALL_VARIABLES = {"a": ("float64", (3,)), "b": ("float32", (4,)), "c": ("int32", ()), "k": ("float64", (10,))}


def small(period: float = 0.004, delta: float = 8.0, bandwidth: float = 1e6) -> Subsystem:
    ctl = TaskSpec("ctl", "m", "rtpu0", period, bindings=(
        bind("in-var", "a", (3,)), bind("in-var", "c", (), "int32"), bind("out-var", "b", (4,), "float32"),
        bind("in-const", "k", (10,)),
    ))
    src = TaskSpec("src", "m", "rtpu1", 0.001, bindings=(
        bind("out-var", "a", (3,)), bind("out-var", "c", (), "int32"), bind("out-const", "k", (10,)),
    ))
    return subsystem(SMALL_VARIABLES, [src, ctl], {"run": ["src", "ctl"]}, bandwidth=bandwidth, delta=delta)


# --- eq. 1 ---------------------------------------------------------------------------------------


def test_z_of_a_task_equals_the_hand_computed_value():
    # in: a (24 B) + c (4 B); out: b (16 B); 2Δ = 16 B; T = 4 ms -> 60 B / 0.004 s = 15,000 B/s
    load = bus_model.predict(small(), "run").task("ctl")
    assert load.bytes_in == 28
    assert load.bytes_out == 16
    assert load.per_cycle_bytes == 60
    assert load.rate_bytes_per_s == pytest.approx(15_000.0)
    assert load.period == 0.004
    assert load.lock_bytes == 16


def test_consts_are_not_counted_in_the_per_cycle_load():
    report = bus_model.predict(small(), "run")
    # k (80 B) is an in-const of ctl and an out-const of src: neither counts
    assert report.task("ctl").bytes_in == 28
    # src writes a (24 B) and c (4 B) per cycle, k only at init: (28 + 16) / 0.001 = 44,000 B/s
    assert report.task("src").bytes_out == 28
    assert report.task("src").rate_bytes_per_s == pytest.approx(44_000.0)


def test_in_both_and_out_both_ports_count_every_cycle():
    both = TaskSpec("both", "m", "rtpu0", 0.002, bindings=(
        bind("in-both", "a", (3,)), bind("out-both", "b", (4,), "float32"),
    ))
    sub = subsystem(SMALL_VARIABLES, [both], {"run": ["both"]}, delta=8.0)
    load = bus_model.predict(sub, "run").task("both")
    assert (load.bytes_in, load.bytes_out) == (24, 16)
    assert load.rate_bytes_per_s == pytest.approx((24 + 16 + 16) / 0.002)  # 28,000 B/s


def test_a_task_with_no_per_cycle_ports_still_pays_the_two_locks():
    idle = TaskSpec("idle", "m", "rtpu0", 0.01, bindings=(bind("in-const", "k", (10,)),))
    load = bus_model.predict(subsystem(SMALL_VARIABLES, [idle], {"run": ["idle"]}, delta=8.0), "run").task("idle")
    assert load.rate_bytes_per_s == pytest.approx(16 / 0.01)


def test_the_transfer_size_uses_the_bound_shape_and_the_variable_dtype():
    sub = small()
    assert bus_model.transfer_bytes(sub, bind("in-var", "b", (4,), "float32")) == 16
    assert bus_model.transfer_bytes(sub, bind("in-var", "c", (), "int32")) == 4


def test_an_aperiodic_task_uses_its_minimum_interarrival_time():
    sporadic = _AperiodicTask("sporadic", "m", "rtpu0", 1.0, bindings=(bind("in-var", "a", (3,)),),
                              aperiodic=True, min_interarrival=0.005)
    load = bus_model.predict(subsystem(SMALL_VARIABLES, [sporadic], {"run": ["sporadic"]}, delta=8.0), "run").task("sporadic")
    assert load.aperiodic
    assert load.period == 0.005
    assert load.rate_bytes_per_s == pytest.approx((24 + 16) / 0.005)  # 8,000 B/s, not 40 B/s


def test_an_aperiodic_task_without_a_minimum_interarrival_time_is_an_error():
    unbounded = _AperiodicTask("unbounded", "m", "rtpu0", 1.0, aperiodic=True, min_interarrival=None)
    sub = subsystem(SMALL_VARIABLES, [unbounded], {"run": ["unbounded"]})
    with pytest.raises(BusModelError, match=r"unbounded.*inter-arrival"):
        bus_model.predict(sub, "run")


# --- eq. 2 ---------------------------------------------------------------------------------------


def test_b_is_the_sum_of_the_tasks_z():
    report = bus_model.predict(small(), "run")
    assert report.total == pytest.approx(44_000.0 + 15_000.0)
    assert report.total == pytest.approx(sum(t.rate_bytes_per_s for t in report.tasks))


def test_share_is_b_over_the_bandwidth():
    report = bus_model.predict(small(bandwidth=2e6), "run")
    assert report.bandwidth == 2e6
    assert report.share == pytest.approx(59_000.0 / 2e6)


def test_an_unknown_configuration_is_named_in_the_error():
    with pytest.raises(BusModelError, match=r"no configuration 'nope'.*run"):
        bus_model.predict(small(), "nope")


def test_predict_all_gives_one_report_per_configuration():
    sub = dataclasses.replace(small(), configurations={
        "run": ConfigurationSpec("run", ("src", "ctl")), "alone": ConfigurationSpec("alone", ("ctl",))})
    reports = bus_model.predict_all(sub)
    assert list(reports) == ["run", "alone"]
    assert reports["alone"].total == pytest.approx(15_000.0)


def test_over_bandwidth_finds_a_configuration_when_the_bandwidth_is_tiny():
    assert bus_model.over_bandwidth(small()) == []
    tiny = small(bandwidth=1000.0)
    found = bus_model.over_bandwidth(tiny)
    assert [name for name, _ in found] == ["run"]
    assert found[0][1].share == pytest.approx(59.0)


# --- the demo (TR Figure 8) ------------------------------------------------------------------------


def test_the_demo_file_gives_a_table_with_one_row_per_task():
    sub = load_subsystem(str(DEMO))
    report = bus_model.predict(sub, "joint_pid")
    # pid: 4 in-vars of 6 float64 = 192 B, 1 out-var of 48 B, Δ = 16 B, T = 1 ms
    assert report.task("pid").rate_bytes_per_s == pytest.approx((192 + 48 + 32) / 0.001)  # 272,000 B/s
    table = _bus.as_table(report)
    assert list(table.columns[0].cells) == ["robot", "traj", "pid", "logger", "B (total)"]
    console = Console(record=True, width=200)
    console.print(table)
    text = console.export_text()
    assert "272.0" in text and "0.680 %" in text


def test_the_demo_predicts_b_of_601_6_kb_per_second():
    report = bus_model.predict(load_subsystem(str(DEMO)), "joint_pid")
    # robot 176 B / 1 ms + traj 272 B / 2 ms + pid 272 B / 1 ms + logger 176 B / 10 ms
    assert report.total == pytest.approx(176_000 + 136_000 + 272_000 + 17_600)
    assert report.share == pytest.approx(601_600 / 40e6)


# --- measured --------------------------------------------------------------------------------------


def synthetic_run() -> dict:
    return {"subsystem": "hand", "configuration": "run", "duration": 2.0, "tasks": {
        "src": {"rtpu": "rtpu1", "cycles": 1990, "bytes_per_cycle": 28},
        "ctl": {"rtpu": "rtpu0", "cycles": 400, "bytes_per_cycle": 44},
    }}


def test_measured_uses_cycles_bytes_per_cycle_the_locks_and_the_duration():
    report = _bus.measured(small(), synthetic_run())
    assert report.kind == "measured"
    # ctl: 400 cycles * (44 B + 2Δ = 16 B) / 2 s = 12,000 B/s; src: 1990 * 44 / 2 = 43,780 B/s
    assert report.task("ctl").rate_bytes_per_s == pytest.approx(12_000.0)
    assert report.task("src").rate_bytes_per_s == pytest.approx(43_780.0)
    assert report.total == pytest.approx(55_780.0)
    assert report.task("ctl").period == pytest.approx(2.0 / 400)
    assert report.task("ctl").cycles == 400


def test_a_task_missing_from_the_run_report_ran_no_cycle():
    run = synthetic_run()
    del run["tasks"]["ctl"]
    report = _bus.measured(small(), run)
    assert report.task("ctl").rate_bytes_per_s == 0.0
    assert report.task("ctl").cycles == 0


def test_measured_needs_a_positive_duration():
    with pytest.raises(BusModelError, match="duration"):
        _bus.measured(small(), {**synthetic_run(), "duration": 0.0})


# --- output ----------------------------------------------------------------------------------------


def test_the_table_shows_predicted_and_measured_side_by_side():
    sub = small()
    table = _bus.as_table(bus_model.predict(sub, "run"), _bus.measured(sub, synthetic_run()))
    headers = [c.header for c in table.columns]
    assert "Z_j kB/s predicted" in headers and "Z_j kB/s measured" in headers
    cells = {c.header: list(c.cells) for c in table.columns}
    assert cells["Z_j kB/s predicted"][1] == "15.0"
    assert cells["Z_j kB/s measured"][1] == "12.0"


def test_csv_has_a_header_and_one_line_per_task_plus_total():
    text = _bus.as_csv(bus_model.predict(small(), "run"))
    rows = list(csv.DictReader(io.StringIO(text)))
    assert text.splitlines()[0].startswith("configuration,task,rtpu,period_s")
    assert [r["task"] for r in rows] == ["src", "ctl", "TOTAL"]
    assert float(rows[1]["rate_bytes_per_s"]) == pytest.approx(15_000.0)
    assert float(rows[2]["rate_bytes_per_s"]) == pytest.approx(59_000.0)


def test_csv_with_measured_adds_the_measured_columns():
    sub = small()
    text = _bus.as_csv(bus_model.predict(sub, "run"), _bus.measured(sub, synthetic_run()))
    rows = list(csv.DictReader(io.StringIO(text)))
    assert float(rows[1]["measured_rate_bytes_per_s"]) == pytest.approx(12_000.0)
    assert float(rows[2]["measured_rate_bytes_per_s"]) == pytest.approx(55_780.0)


def test_json_round_trips_through_json_dumps():
    sub = small()
    data = _bus.as_json(bus_model.predict(sub, "run"), _bus.measured(sub, synthetic_run()))
    again = json.loads(json.dumps(data, allow_nan=False))
    assert again == data
    assert again["predicted"]["total"] == pytest.approx(59_000.0)
    assert again["measured"]["tasks"][1]["cycles"] == 400


def test_json_of_a_task_that_never_ran_has_no_infinite_period():
    run = synthetic_run()
    del run["tasks"]["ctl"]
    data = _bus.as_json(bus_model.predict(small(), "run"), _bus.measured(small(), run))
    json.dumps(data, allow_nan=False)
    assert data["measured"]["tasks"][1]["period"] is None


def test_plot_writes_a_non_empty_png(tmp_path):
    sub = load_subsystem(str(DEMO))
    report = bus_model.predict(sub, "joint_pid")
    path = _bus.plot({"joint_pid": report}, tmp_path / "bus.png")
    data = path.read_bytes()
    assert len(data) > 1000
    assert data[:8] == PNG_SIGNATURE


def test_plot_accepts_several_reports_and_measured_ones(tmp_path):
    sub = small()
    path = _bus.plot([bus_model.predict(sub, "run"), bus_model.predict(small(bandwidth=1e5), "run")], tmp_path / "two.png",
                     measured={"run": _bus.measured(sub, synthetic_run())})
    assert path.read_bytes()[:8] == PNG_SIGNATURE


# --- combined modules (TR §4.5) --------------------------------------------------------------------

# s, u, v: 2 float64 = 16 B each; Δ = 4 B so 2Δ = 8 B.
#   sense (rtpu1, 1 ms): out s                 (16 + 8) / 1 ms = 24,000 B/s
#   a     (rtpu0, 2 ms): in s, out u           (16 + 16 + 8) / 2 ms = 20,000 B/s
#   c     (rtpu0, 1 ms): in u, in s, out v     (32 + 16 + 8) / 1 ms = 56,000 B/s
#   act   (rtpu1, 1 ms): in v                  (16 + 8) / 1 ms = 24,000 B/s      B = 124,000 B/s
# a+c combined at 1 ms: s read once (16 B), u stays local, v written (16 B):
#   (16 + 16 + 8) / 1 ms = 40,000 B/s                                         B = 88,000 B/s
CHAIN_VARIABLES = {"s": ("float64", (2,)), "u": ("float64", (2,)), "v": ("float64", (2,))}


def chain(act_reads_u: bool = False) -> Subsystem:
    act_bindings = (bind("in-var", "v", (2,)),) + ((bind("in-var", "u", (2,)),) if act_reads_u else ())
    tasks = [
        TaskSpec("sense", "m", "rtpu1", 0.001, bindings=(bind("out-var", "s", (2,)),)),
        TaskSpec("a", "m", "rtpu0", 0.002, bindings=(bind("in-var", "s", (2,)), bind("out-var", "u", (2,)))),
        TaskSpec("c", "m", "rtpu0", 0.001, bindings=(
            bind("in-var", "u", (2,)), bind("in-var", "s", (2,)), bind("out-var", "v", (2,)))),
        TaskSpec("act", "m", "rtpu1", 0.001, bindings=act_bindings),
    ]
    return subsystem(CHAIN_VARIABLES, tasks, {"loop": ["sense", "a", "c", "act"]}, bandwidth=1e6, delta=4.0)


def test_combining_keeps_linking_variables_local_and_reads_shared_inputs_once():
    before, after = _bus.combined_saving(chain(), "loop", ["a", "c"])
    assert before.total == pytest.approx(124_000.0)
    assert [t.task for t in after.tasks] == ["sense", "a+c", "act"]
    combined = after.task("a+c")
    assert combined.period == 0.001  # the fastest member's period
    assert (combined.bytes_in, combined.bytes_out) == (16, 16)
    assert combined.rate_bytes_per_s == pytest.approx(40_000.0)
    assert after.total == pytest.approx(88_000.0)
    assert before.total - after.total == pytest.approx(36_000.0)
    assert after.kind == "combined"


def test_a_member_output_read_by_another_task_is_still_written_after_combining():
    before, after = _bus.combined_saving(chain(act_reads_u=True), "loop", ["a", "c"])
    # act now reads u too: u is written (16 B more) and act pays 16 B more per cycle
    assert after.task("a+c").bytes_out == 32
    assert after.task("a+c").rate_bytes_per_s == pytest.approx(56_000.0)
    assert after.task("act").rate_bytes_per_s == pytest.approx(40_000.0)
    # before: 24,000 + 20,000 + 56,000 + 40,000 = 140,000; after: 24,000 + 56,000 + 40,000 = 120,000
    assert before.total == pytest.approx(140_000.0)
    assert after.total == pytest.approx(120_000.0)


def test_combining_members_on_different_rtpus_is_refused():
    with pytest.raises(BusModelError, match="cannot be distributed"):
        _bus.combined_saving(chain(), "loop", ["sense", "a"])


def test_combining_a_task_outside_the_configuration_is_refused():
    with pytest.raises(BusModelError, match="not in configuration"):
        _bus.combined_saving(chain(), "loop", ["a", "ghost"])


def test_combining_the_demo_trajectory_and_pid_saves_the_trajectory_outputs_read_only_by_pid():
    sub = load_subsystem(str(DEMO))
    before, after = _bus.combined_saving(sub, "joint_pid", ["traj", "pid"])
    # in: q_d, q_m, qd_m (144 B); out: q_r (the logger reads it) and tau_u (96 B); qd_r stays local
    assert after.task("traj+pid").rate_bytes_per_s == pytest.approx((144 + 96 + 32) / 0.001)
    assert after.total == pytest.approx(601_600 - 136_000)
    assert "saves 136.0 kB/s" in _bus.describe_saving(before, after)
