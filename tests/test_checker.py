"""The checker's rules (DESIGN.md §6, §12): one legal and one illegal case per rule.

Each illegal case changes one thing in a legal file and expects exactly one error, at the
line and column of the offending node, with an anchored message.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import Any

import pytest

from pbo_runtime import InBoth, InConst, InVar, ModuleError, OutBoth, OutConst, OutVar, PortBasedObject
from pbo_runtime._config_loader import CheckResult, check_file
from pbo_runtime._errors import ConfigError

# --- fake modules ------------------------------------------------------------------------


class FakeRobot(PortBasedObject):
    ndof = InConst("NDOF", dtype="int32")
    tau = InVar("tau_u", shape=("NDOF",))
    q = OutVar("q_m", shape=("NDOF",))


@dataclasses.dataclass(frozen=True)
class FakePidParams:
    kp: float
    kd: float = 0.0


class FakePid(PortBasedObject):
    Params = FakePidParams
    ndof = InConst("NDOF", dtype="int32")
    q_r = InVar("q_r", shape=("NDOF",))
    q_m = InVar("q_m", shape=("NDOF",))
    tau = OutVar("tau", shape=("NDOF",))


class FakeTraj(PortBasedObject):
    q_d = InVar("q_d", shape=("NDOF",))
    q_r = OutVar("q_r", shape=("NDOF",))


class FakeGravity(PortBasedObject):
    tau = OutVar("tau_u", shape=("NDOF",))


class FakeNdofConst(PortBasedObject):
    ndof = OutConst("NDOF", dtype="int32")


class FakeNdofVar(PortBasedObject):
    ndof = OutVar("NDOF", dtype="int32")


class FakeConstA(PortBasedObject):
    b = InConst("b")
    a = OutConst("a")


class FakeConstB(PortBasedObject):
    a = InConst("a")
    b = OutConst("b")


class FakeBothReader(PortBasedObject):
    c = InBoth("c")


class FakeBothWriter(PortBasedObject):
    c = OutBoth("c")


class FakeNeedsDim(PortBasedObject):
    x = InVar("x", shape=("NJOINTS",))


class FakeBroken(PortBasedObject):
    @classmethod
    def ports(cls) -> tuple[Any, ...]:
        raise RuntimeError("ports table is corrupt")


FAKES: dict[str, type] = {
    "fake_robot": FakeRobot,
    "fake_pid": FakePid,
    "fake_traj": FakeTraj,
    "fake_gravity": FakeGravity,
    "fake_ndof_const": FakeNdofConst,
    "fake_ndof_var": FakeNdofVar,
    "fake_const_a": FakeConstA,
    "fake_const_b": FakeConstB,
    "fake_both_reader": FakeBothReader,
    "fake_both_writer": FakeBothWriter,
    "fake_needs_dim": FakeNeedsDim,
    "fake_broken": FakeBroken,
}


def fake_lookup(name: str) -> type:
    try:
        return FAKES[name]
    except KeyError:
        raise ModuleError(f"no module named '{name}'") from None


# --- a legal file and helpers --------------------------------------------------------------

LEGAL = """\
subsystem: puma
rtpus: [rtpu0, rtpu1]
devices:
  arm: {driver: fake_arm, exclusive: true}
dims: {NDOF: 6}
variables:
  NDOF:  {type: int32, initial: 6}
  q_m:   {type: float64, shape: [NDOF]}
  q_r:   {type: float64, shape: [NDOF]}
  q_d:   {type: float64, shape: [NDOF], object: joint_position}
  tau_u: {type: float64, shape: [NDOF]}
tasks:
  robot: {module: fake_robot, rtpu: rtpu1, period: 1 ms, critical: true, resources: [arm]}
  traj:  {module: fake_traj, rtpu: rtpu0, period: 2 ms}
  pid:   {module: fake_pid, rtpu: rtpu0, rate: 1 kHz, params: {kp: 400}, ports: {tau: tau_u}}
configurations:
  joint_pid: [robot, traj, pid]
jobs:
  move: {configuration: joint_pid, object: q_d, post: "max(abs(q_m - q_d)) < 1e-3", timeout: 10 s}
applications:
  demo:
    - move: {q_d: [0, -0.5, 0.5, 0, 0, 0]}
"""


def check(tmp_path: Path, text: str) -> CheckResult:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    return check_file(path, fake_lookup, module_names=lambda: FAKES)


def changed(old: str, new: str, text: str = LEGAL) -> str:
    assert old in text, f"{old!r} is not in the file"
    return text.replace(old, new, 1)


def at(text: str, needle: str, nth: int = 0) -> tuple[int, int]:
    """1-based line and column of the nth occurrence of `needle`."""
    start = -1
    for _ in range(nth + 1):
        start = text.index(needle, start + 1)
    line = text.count("\n", 0, start) + 1
    column = start - (text.rfind("\n", 0, start) + 1) + 1
    return line, column


def only_error(result: CheckResult) -> ConfigError:
    assert len(result.errors) == 1, "\n".join(e.format() for e in result.errors)
    return result.errors[0]


def expect_error(tmp_path: Path, text: str, needle: str, message: str, nth: int = 0) -> ConfigError:
    """Exactly one error, at `needle`, whose text matches `message` (a regex) after the location."""
    error = only_error(check(tmp_path, text))
    line, column = at(text, needle, nth)
    assert re.match(rf"^.*bad\.yaml:{line}:{column}: error: {message}", str(error), re.MULTILINE), str(error)
    return error


# --- the legal file ------------------------------------------------------------------------


def test_the_legal_file_has_no_error_and_no_warning(tmp_path: Path) -> None:
    result = check(tmp_path, LEGAL)
    assert result.errors == []
    assert result.warnings == []
    assert result.subsystem is not None


# --- keys and types ------------------------------------------------------------------------


def test_an_unknown_top_level_key_is_an_error_with_a_suggestion(tmp_path: Path) -> None:
    text = changed("dims:", "dimz:")
    error = check(tmp_path, text).errors[0]
    assert (error.line, error.column) == at(text, "dimz")
    assert re.match(r"^unknown key 'dimz' at the top level$", error.message)
    assert error.hint.startswith("did you mean 'dims'?")


def test_an_unknown_key_in_a_task_is_an_error_with_a_suggestion(tmp_path: Path) -> None:
    text = changed("critical: true", "critcal: true")
    error = expect_error(tmp_path, text, "critcal", r"unknown key 'critcal' in task 'robot'$")
    assert "did you mean 'critical'?" in error.hint


def test_an_unknown_key_in_a_variable_is_an_error(tmp_path: Path) -> None:
    text = changed("q_r:   {type: float64,", "q_r:   {type: float64, units: rad,")
    expect_error(tmp_path, text, "units", r"unknown key 'units' in variable 'q_r'$")


def test_a_missing_required_top_level_key_is_an_error(tmp_path: Path) -> None:
    text = changed("rtpus: [rtpu0, rtpu1]\n", "")
    result = check(tmp_path, text)
    assert any(re.match(r"^the file has no 'rtpus:', which is required$", e.message) for e in result.errors)


def test_a_misspelt_required_key_is_one_error_not_two(tmp_path: Path) -> None:
    text = LEGAL.replace("module: fake_robot", "modul: fake_robot")
    expect_error(tmp_path, text, "modul:", r"unknown key 'modul' in task 'robot': did you mean the required key 'module'\?$")


def test_a_task_without_a_module_is_an_error_at_the_task(tmp_path: Path) -> None:
    text = changed("module: fake_traj, ", "")
    expect_error(tmp_path, text, "traj:", r"task 'traj' has no 'module:', which is required$")


def test_a_section_of_the_wrong_type_is_an_error(tmp_path: Path) -> None:
    text = changed("dims: {NDOF: 6}", "dims: 6")
    result = check(tmp_path, text)
    error = result.errors[0]
    assert re.match(r"^'dims' must be a mapping, got: the integer 6$", error.message)
    assert (error.line, error.column) == at(text, "6", 0)


def test_a_flag_that_is_not_a_boolean_is_an_error(tmp_path: Path) -> None:
    text = changed("critical: true", "critical: yes please")
    expect_error(tmp_path, text, "yes please", r"'critical' of task 'robot' must be true or false, got: the text 'yes please'$")


def test_an_invalid_subsystem_name_is_an_error(tmp_path: Path) -> None:
    text = changed("subsystem: puma", "subsystem: my puma/1")
    expect_error(tmp_path, text, "my puma", r"subsystem name 'my puma/1' is not usable in shared-memory names$")


def test_rtpus_may_be_a_mapping_with_cpus(tmp_path: Path) -> None:
    result = check(tmp_path, changed("rtpus: [rtpu0, rtpu1]", "rtpus: {rtpu0: {cpu: 0}, rtpu1: {cpu: 1}}"))
    assert result.errors == []
    assert result.subsystem is not None
    assert [(r.name, r.index, r.cpu) for r in result.subsystem.rtpus] == [("rtpu0", 0, 0), ("rtpu1", 1, 1)]


def test_an_rtpu_cpu_must_be_a_non_negative_integer(tmp_path: Path) -> None:
    text = changed("rtpus: [rtpu0, rtpu1]", "rtpus: {rtpu0: {cpu: -1}, rtpu1: {cpu: 1}}")
    expect_error(tmp_path, text, "-1", r"cpu of RTPU 'rtpu0' must be >= 0, got: -1$")


# --- undefined names -----------------------------------------------------------------------


def test_a_port_linked_to_an_undefined_variable_is_an_error_with_a_suggestion(tmp_path: Path) -> None:
    text = changed("ports: {tau: tau_u}", "ports: {tau: tau_uu}")
    error = expect_error(tmp_path, text, "tau_uu", r"task 'pid' links port 'tau' to variable 'tau_uu', which 'variables' does not declare$")
    assert error.hint.startswith("did you mean 'tau_u'?")


def test_a_port_linked_by_default_to_an_undeclared_variable_is_an_error(tmp_path: Path) -> None:
    text = changed(", ports: {tau: tau_u}", "")
    error = expect_error(
        tmp_path, text, "pid:", r"task 'pid' \(module 'fake_pid'\) links port 'tau' by default to variable 'tau', which 'variables' does not declare$"
    )
    assert "ports: {tau: <variable>}" in error.hint


def test_an_unknown_module_is_an_error_with_a_suggestion(tmp_path: Path) -> None:
    text = changed("module: fake_traj", "module: fake_trajj")
    error = expect_error(tmp_path, text, "fake_trajj", r"task 'traj' uses module 'fake_trajj', which is not registered$")
    assert error.hint.startswith("did you mean 'fake_traj'? (registered: ")


def test_an_unknown_rtpu_is_an_error_with_a_suggestion(tmp_path: Path) -> None:
    text = changed("rtpu: rtpu1", "rtpu: rtpu2")
    error = expect_error(tmp_path, text, "rtpu2", r"task 'robot' runs on RTPU 'rtpu2', which 'rtpus' does not declare$")
    assert re.match(r"^did you mean 'rtpu[01]'\? \(declared: rtpu0, rtpu1\)$", error.hint)


def test_an_unknown_device_is_an_error(tmp_path: Path) -> None:
    text = changed("resources: [arm]", "resources: [army]")
    expect_error(tmp_path, text, "army", r"task 'robot' uses device 'army', which 'devices' does not declare$")


def test_an_unknown_dim_in_a_shape_is_an_error(tmp_path: Path) -> None:
    text = changed("q_d:   {type: float64, shape: [NDOF]", "q_d:   {type: float64, shape: [NDFO]")
    error = expect_error(tmp_path, text, "NDFO", r"shape of variable 'q_d' uses dim 'NDFO', which 'dims' does not define$")
    assert "did you mean 'NDOF'?" in error.hint


def test_a_port_shape_naming_an_undefined_dim_is_an_error(tmp_path: Path) -> None:
    text = changed("  demo:\n", "  demo:\n", LEGAL)
    text = changed("tasks:\n", "tasks:\n  needs: {module: fake_needs_dim, rtpu: rtpu0, period: 1 ms}\n", text)
    text = changed("q_d:   {", "x: {type: float64, shape: [3]}\n  q_d:   {", text)
    text = changed("[robot, traj, pid]", "[robot, traj, pid, needs]", text)
    result = check(tmp_path, text)
    error = only_error(result)
    assert re.match(r"^port 'x' of module 'fake_needs_dim' \(task 'needs'\) has shape \(NJOINTS,\) with dim 'NJOINTS'", error.message)


def test_an_unknown_task_in_a_configuration_is_an_error(tmp_path: Path) -> None:
    text = changed("[robot, traj, pid]", "[robot, traj, pid, gravity]")
    expect_error(tmp_path, text, "gravity", r"configuration 'joint_pid' names task 'gravity', which 'tasks' does not declare$")


def test_an_unknown_configuration_in_a_job_is_an_error(tmp_path: Path) -> None:
    text = changed("configuration: joint_pid", "configuration: joint_pd")
    error = expect_error(tmp_path, text, "joint_pd,", r"job 'move' runs configuration 'joint_pd', which 'configurations' does not declare$")
    assert error.hint.startswith("did you mean 'joint_pid'?")


def test_a_port_the_module_does_not_declare_is_an_error(tmp_path: Path) -> None:
    text = changed("ports: {tau: tau_u}", "ports: {tau: tau_u, torque: tau_u}")
    error = expect_error(tmp_path, text, "torque", r"module 'fake_pid' of task 'pid' has no port 'torque'$")
    assert error.hint == "(ports: ndof, q_m, q_r, tau)"


# --- ports and variables agree ---------------------------------------------------------------


def test_a_port_and_its_variable_must_have_the_same_dtype(tmp_path: Path) -> None:
    text = changed("q_d:   {type: float64", "q_d:   {type: float32")
    error = expect_error(tmp_path, text, "traj:", r"task 'traj' port 'q_d' \(in-var\) is float64, but variable 'q_d' is float32$")
    assert error.hint == "change the type of 'q_d' (line 10) or link the port to a float64 variable"


def test_a_port_and_its_variable_must_have_the_same_resolved_shape(tmp_path: Path) -> None:
    text = changed("q_r:   {type: float64, shape: [NDOF]}", "q_r:   {type: float64, shape: [7]}")
    result = check(tmp_path, text)
    assert len(result.errors) == 2  # traj writes it, pid reads it
    error = result.errors[0]
    assert re.match(r"^task 'traj' port 'q_r' \(out-var\) has shape \(6,\) = \(NDOF,\), but variable 'q_r' has shape \(7,\)$", error.message)


def test_an_unknown_dtype_is_an_error_with_the_valid_ones(tmp_path: Path) -> None:
    text = changed("q_d:   {type: float64", "q_d:   {type: float46")
    error = expect_error(tmp_path, text, "float46", r"variable 'q_d' has unknown type 'float46'$")
    assert error.hint.startswith("did you mean 'float64'? (valid: bool, float32, float64, int32, int64, uint8)")


# --- producers and consumers -----------------------------------------------------------------


def test_an_input_nobody_writes_is_an_error_naming_the_configuration(tmp_path: Path) -> None:
    text = changed("[robot, traj, pid]", "[robot, pid]")
    text = changed("  move:", "  move:", text)
    result = check(tmp_path, text)
    error = only_error(result)
    line, column = at(text, "pid:")
    assert re.match(
        rf"^.*bad\.yaml:{line}:{column}: error: task 'pid' reads in-var 'q_r', but no task in configuration 'joint_pid' writes it",
        str(error),
    )
    assert "written: " in error.hint


def test_an_object_or_an_initial_value_counts_as_written_by_job_control(tmp_path: Path) -> None:
    # q_d (object) is read by traj and NDOF (initial) by robot and pid, and nobody writes them.
    assert check(tmp_path, LEGAL).errors == []


def test_a_variable_cannot_have_two_writers_in_one_configuration(tmp_path: Path) -> None:
    text = changed("tasks:\n", "tasks:\n  gravity: {module: fake_gravity, rtpu: rtpu0, period: 1 ms}\n")
    text = changed("[robot, traj, pid]", "[robot, traj, gravity, pid]", text)
    error = only_error(check(tmp_path, text))
    line, column = at(text, "tau_u}")
    grav_line, _ = at(text, "gravity:")
    assert re.match(
        rf"^.*bad\.yaml:{line}:{column}: error: variable 'tau_u' has two writers in configuration 'joint_pid': "
        rf"'gravity' \(line {grav_line}\) and 'pid' \(line {line}\)$",
        error.format().splitlines()[0],
    )
    assert error.hint == "an output has one writer; join them with a join connector (TR Figure 6)"


def test_two_writers_in_different_configurations_are_legal(tmp_path: Path) -> None:
    text = changed("tasks:\n", "tasks:\n  gravity: {module: fake_gravity, rtpu: rtpu0, period: 1 ms}\n")
    text = changed("configurations:\n", "configurations:\n  hold: [robot, gravity]\n", text)
    assert check(tmp_path, text).errors == []


def test_in_const_cannot_take_an_out_var(tmp_path: Path) -> None:
    text = changed("NDOF:  {type: int32, initial: 6}", "NDOF:  {type: int32}")
    text = changed("tasks:\n", "tasks:\n  dims: {module: fake_ndof_var, rtpu: rtpu0, period: 1 ms}\n", text)
    text = changed("[robot, traj, pid]", "[dims, robot, traj, pid]", text)
    result = check(tmp_path, text)
    assert len(result.errors) == 2  # robot and pid both read NDOF as in-const
    line, column = at(text, "robot:")
    assert re.match(
        rf"^.*bad\.yaml:{line}:{column}: error: task 'robot' reads in-const 'NDOF' before its init, but its writer 'dims' "
        r"in configuration 'joint_pid' writes it as out-var \(only after each cycle\)",
        str(result.errors[0]),
    )


def test_in_const_takes_an_out_const(tmp_path: Path) -> None:
    text = changed("NDOF:  {type: int32, initial: 6}", "NDOF:  {type: int32}")
    text = changed("tasks:\n", "tasks:\n  dims: {module: fake_ndof_const, rtpu: rtpu0, period: 1 ms}\n", text)
    text = changed("[robot, traj, pid]", "[dims, robot, traj, pid]", text)
    assert check(tmp_path, text).errors == []


def test_in_const_cannot_take_a_job_object_without_an_initial_value(tmp_path: Path) -> None:
    text = changed("NDOF:  {type: int32, initial: 6}", "NDOF:  {type: int32, object: count}")
    result = check(tmp_path, text)
    assert len(result.errors) == 2
    assert re.match(r"^task 'robot' reads in-const 'NDOF' before its init, but in configuration 'joint_pid' only job control", result.errors[0].message)


def test_in_both_takes_an_out_both(tmp_path: Path) -> None:
    text = changed("variables:\n", "variables:\n  c: {type: float64}\n")
    text = changed("tasks:\n", "tasks:\n  w: {module: fake_both_writer, rtpu: rtpu0, period: 1 ms}\n  r: {module: fake_both_reader, rtpu: rtpu0, period: 1 ms}\n", text)
    text = changed("configurations:\n", "configurations:\n  both: [w, r]\n", text)
    assert check(tmp_path, text).errors == []


def test_in_both_without_a_writer_is_an_error(tmp_path: Path) -> None:
    text = changed("variables:\n", "variables:\n  c: {type: float64}\n")
    text = changed("tasks:\n", "tasks:\n  w: {module: fake_both_writer, rtpu: rtpu0, period: 1 ms}\n  r: {module: fake_both_reader, rtpu: rtpu0, period: 1 ms}\n", text)
    text = changed("configurations:\n", "configurations:\n  both: [r]\n  other: [w]\n", text)
    expect_error(tmp_path, text, "r: {module", r"task 'r' reads in-both 'c', but no task in configuration 'both' writes it")


def test_a_task_appears_at_most_once_in_a_configuration(tmp_path: Path) -> None:
    text = changed("[robot, traj, pid]", "[robot, traj, pid, traj]")
    error = expect_error(tmp_path, text, "traj", r"task 'traj' appears twice in configuration 'joint_pid' \(first at line 17, column 22\)$", nth=3)
    assert "declare a second task" in error.hint


def test_a_cycle_of_const_dependencies_is_an_error_that_prints_the_cycle(tmp_path: Path) -> None:
    text = changed("variables:\n", "variables:\n  a: {type: float64}\n  b: {type: float64}\n")
    text = changed("tasks:\n", "tasks:\n  ta: {module: fake_const_a, rtpu: rtpu0, period: 1 ms}\n  tb: {module: fake_const_b, rtpu: rtpu0, period: 1 ms}\n", text)
    text = changed("configurations:\n", "configurations:\n  consts: [ta, tb]\n", text)
    error = only_error(check(tmp_path, text))
    assert re.match(r"^const dependencies form a cycle: (ta -> tb -> ta|tb -> ta -> tb)$", error.message)
    assert (error.line, error.column) == at(text, error.message.split(": ")[1].split(" ")[0] + ":")
    assert "'ta' writes 'a' that 'tb' reads before its init" in error.hint


def test_the_init_order_puts_const_producers_first_then_file_order(tmp_path: Path) -> None:
    text = changed("NDOF:  {type: int32, initial: 6}", "NDOF:  {type: int32}")
    text = changed("configurations:\n", "  dims: {module: fake_ndof_const, rtpu: rtpu0, period: 1 ms}\nconfigurations:\n", text)
    text = changed("[robot, traj, pid]", "[robot, traj, pid, dims]", text)
    result = check(tmp_path, text)
    assert result.errors == []
    assert result.subsystem is not None
    assert result.subsystem.init_order == ("traj", "dims", "robot", "pid")


# --- periods ---------------------------------------------------------------------------------


def test_a_period_must_be_positive(tmp_path: Path) -> None:
    text = changed("period: 2 ms", "period: -5 ms")
    expect_error(tmp_path, text, "-5 ms", r"period of task 'traj' must be > 0, got: -5 ms$")


def test_a_rate_must_be_positive(tmp_path: Path) -> None:
    text = changed("rate: 1 kHz", "rate: 0 Hz")
    expect_error(tmp_path, text, "0 Hz", r"rate of task 'pid' must be > 0, got: 0 Hz$")


def test_a_task_cannot_give_both_period_and_rate(tmp_path: Path) -> None:
    text = changed("rate: 1 kHz", "rate: 1 kHz, period: 1 ms")
    expect_error(tmp_path, text, "rate:", r"task 'pid' gives both a period and a rate$")


def test_a_task_needs_a_period_or_a_rate(tmp_path: Path) -> None:
    text = changed(", period: 2 ms", "")
    expect_error(tmp_path, text, "traj:", r"task 'traj' needs a period or a rate$")


def test_a_period_in_frequency_units_says_to_use_rate(tmp_path: Path) -> None:
    text = changed("period: 2 ms", "period: 500 Hz")
    error = expect_error(tmp_path, text, "500 Hz", r"period of task 'traj': expected a time like '1 ms' or a number of seconds, got: '500 Hz' \(that is a frequency\)$")
    assert "rate: 1 kHz" in error.hint


def test_a_rate_becomes_a_period(tmp_path: Path) -> None:
    result = check(tmp_path, LEGAL)
    assert result.subsystem is not None
    assert result.subsystem.tasks["pid"].period == pytest.approx(1e-3)


# --- devices ---------------------------------------------------------------------------------


def test_an_exclusive_device_has_one_user_per_configuration(tmp_path: Path) -> None:
    text = changed("period: 2 ms}", "period: 2 ms, resources: [arm]}")
    arm_line, _ = at(text, "resources: [arm]")
    error = expect_error(tmp_path, text, "arm", rf"device 'arm' is exclusive, but configuration 'joint_pid' gives it to 'robot' \(line {arm_line}\) and 'traj'", nth=3)
    assert "exclusive: false" in error.hint


def test_a_shared_device_may_have_many_users(tmp_path: Path) -> None:
    text = changed("exclusive: true", "exclusive: false")
    text = changed("period: 2 ms}", "period: 2 ms, resources: [arm]}", text)
    assert check(tmp_path, text).errors == []


# --- values ----------------------------------------------------------------------------------


def test_an_initial_value_must_match_the_shape(tmp_path: Path) -> None:
    text = changed("q_m:   {type: float64, shape: [NDOF]}", "q_m:   {type: float64, shape: [NDOF], initial: [1, 2, 3]}")
    expect_error(tmp_path, text, "[1, 2, 3]", r"initial value of variable 'q_m' has shape \(3,\), but the variable's shape is \(6,\)$")


def test_an_initial_value_must_fit_the_dtype(tmp_path: Path) -> None:
    text = changed("initial: 6}", "initial: 6.5}")
    expect_error(tmp_path, text, "6.5", r"initial value of variable 'NDOF': int32 elements must be integers, got: the number 6.5$")


def test_one_number_initialises_every_element(tmp_path: Path) -> None:
    text = changed("q_m:   {type: float64, shape: [NDOF]}", "q_m:   {type: float64, shape: [NDOF], initial: 0}")
    result = check(tmp_path, text)
    assert result.errors == []
    assert result.initial_values["q_m"].shape == (6,)


def test_a_ragged_initial_value_is_an_error(tmp_path: Path) -> None:
    text = changed("dims: {NDOF: 6}", "dims: {NDOF: 6}\n")
    text = changed("q_m:   {type: float64, shape: [NDOF]}", "q_m:   {type: float64, shape: [2, 2], initial: [[1, 2], [3]]}", text)
    result = check(tmp_path, text)
    assert any(re.match(r"^initial value of variable 'q_m' is a ragged list", e.message) for e in result.errors)


def test_params_the_module_refuses_are_an_error_at_the_params_node(tmp_path: Path) -> None:
    text = changed("params: {kp: 400}", "params: {kp: 400, ki: 1}")
    error = expect_error(tmp_path, text, "{kp: 400, ki: 1}", r"params of task 'pid' \(module 'fake_pid'\): unknown parameter\(s\) 'ki' for FakePid \(valid: kd, kp\)$")
    assert error.column > 1


def test_missing_params_are_an_error(tmp_path: Path) -> None:
    text = changed(", params: {kp: 400}", "")
    expect_error(tmp_path, text, "pid:", r"params of task 'pid' \(module 'fake_pid'\): missing parameter\(s\) 'kp'")


def test_a_module_that_cannot_list_its_ports_is_reported_not_raised(tmp_path: Path) -> None:
    text = changed("module: fake_traj", "module: fake_broken")
    result = check(tmp_path, text)
    assert any(re.match(r"^module 'fake_broken' of task 'traj' cannot list its ports: RuntimeError", e.message) for e in result.errors)


# --- jobs and applications ------------------------------------------------------------------


def test_a_job_object_must_be_a_variable_marked_as_an_object(tmp_path: Path) -> None:
    text = changed("object: q_d, post", "object: q_m, post")
    expect_error(tmp_path, text, "q_m, post", r"job 'move' takes variable 'q_m' as its object, but the variable is not marked as an object$")


def test_a_job_condition_must_be_an_expression(tmp_path: Path) -> None:
    text = changed('"max(abs(q_m - q_d)) < 1e-3"', '"max(abs(q_m - q_d) < 1e-3"')
    expect_error(tmp_path, text, '"max', r"post-condition of job 'move' is not an expression: ")


def test_an_application_step_must_name_a_job(tmp_path: Path) -> None:
    text = changed("- move:", "- mvoe:")
    error = expect_error(tmp_path, text, "mvoe", r"step 1 of application 'demo' runs job 'mvoe', which 'jobs' does not declare$")
    assert error.hint.startswith("did you mean 'move'?")


def test_an_application_object_must_match_the_variable_shape(tmp_path: Path) -> None:
    text = changed("[0, -0.5, 0.5, 0, 0, 0]", "[0, -0.5, 0.5]")
    expect_error(tmp_path, text, "[0, -0.5, 0.5]", r"object 'q_d' of step 1 of application 'demo' has shape \(3,\), but the variable's shape is \(6,\)$")


def test_an_application_step_without_its_object_is_only_a_warning(tmp_path: Path) -> None:
    text = changed("    - move: {q_d: [0, -0.5, 0.5, 0, 0, 0]}", "    - move")
    result = check(tmp_path, text)
    assert result.errors == []
    assert len(result.warnings) == 1
    assert re.match(r"^.*bad\.yaml:\d+:7: warning: step 1 of application 'demo' runs job 'move' without its object 'q_d'", str(result.warnings[0]))


# --- warnings ------------------------------------------------------------------------------


def test_a_variable_nobody_reads_is_a_warning(tmp_path: Path) -> None:
    text = changed("variables:\n", "variables:\n  spare: {type: float64}\n")
    result = check(tmp_path, text)
    assert result.errors == []
    [warning] = result.warnings
    line, column = at(text, "spare")
    assert str(warning) == f"{tmp_path / 'bad.yaml'}:{line}:{column}: warning: variable 'spare' is read by no task\n  hint: remove it, or link a task's input port to it"


def test_a_task_in_no_configuration_is_a_warning(tmp_path: Path) -> None:
    text = changed("configurations:\n", "  gravity: {module: fake_gravity, rtpu: rtpu0, period: 1 ms}\nconfigurations:\n")
    result = check(tmp_path, text)
    assert result.errors == []
    [warning] = result.warnings
    assert warning.severity == "warning"
    assert warning.message == "task 'gravity' is in no configuration"


# --- all at once -----------------------------------------------------------------------------


def test_three_different_mistakes_are_all_reported_with_their_lines(tmp_path: Path) -> None:
    text = changed("rtpu: rtpu1", "rtpu: rtpu9")
    text = changed("q_d:   {type: float64", "q_d:   {type: float63", text)
    text = changed("timeout: 10 s", "timeout: 10 kg", text)
    result = check(tmp_path, text)
    found = [(e.line, e.message.split(" ")[0:2]) for e in result.errors]
    assert [line for line, _ in found] == [at(text, "float63")[0], at(text, "rtpu9")[0], at(text, "10 kg")[0]], found
    assert re.match(r"^variable 'q_d' has unknown type 'float63'$", result.errors[0].message)
    assert re.match(r"^task 'robot' runs on RTPU 'rtpu9'", result.errors[1].message)
    assert re.match(r"^timeout of job 'move': expected a time like '1 ms'", result.errors[2].message)
