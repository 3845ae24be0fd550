"""The checker's rules: one legal and one illegal case per rule.

Each illegal case changes one thing in a legal file and expects exactly one error, at the
line and column of the offending node, with an anchored message.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import Any

import pytest

from pbo_runtime import ANY_DTYPE, InBoth, InConst, InVar, ModuleError, OutBoth, OutConst, OutVar, PortBasedObject, param
from pbo_runtime.config.loader import CheckResult, check_file
from pbo_runtime.errors import ConfigError

# --- fake modules ------------------------------------------------------------------------


class FakeRobot(PortBasedObject):
    ndof = InConst("NDOF", dtype="int32")
    tau = InVar("tau_u", shape=("NDOF",))
    q = OutVar("q_m", shape=("NDOF",))


@dataclasses.dataclass(frozen=True)
class FakePidParams:
    kp: float | tuple[float, ...] = param(at_least=0, at_most=1e6)  # required, with a range
    kd: float = 0.0  # no range declared: any finite number


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


class FakeKReader(PortBasedObject):
    """Reads K, of any dtype and shape: so a variable added by a case is read, and warns of nothing."""

    k = InVar("K", dtype=ANY_DTYPE, shape=None)


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
    "fake_k_reader": FakeKReader,
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
  arm: {driver: mujoco_arm, exclusive: true}
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


def expect_error(tmp_path: Path, text: str, needle: str, message: str, nth: int = 0, code: str = r"E\d{3}") -> ConfigError:
    """Exactly one error, at `needle`, whose text matches `message` (a regex) after the location and code."""
    error = only_error(check(tmp_path, text))
    line, column = at(text, needle, nth)
    assert re.match(rf"^.*bad\.yaml:{line}:{column}: error\[{code}\]: {message}", str(error), re.MULTILINE), str(error)
    return error


def expect_warnings(result: CheckResult, *codes: str) -> list[ConfigError]:
    assert result.errors == [], "\n".join(e.format() for e in result.errors)
    assert sorted(w.code for w in result.warnings) == sorted(codes), "\n".join(w.format() for w in result.warnings)
    return result.warnings


def edited(*edits: tuple[str, str], text: str = LEGAL) -> str:
    """`text` with each (old, new) edit made in turn, each of them once."""
    for old, new in edits:
        text = changed(old, new, text)
    return text


def with_apps(apps: str, jobs: str = "") -> str:
    """The legal file with its applications replaced by `apps`, and `jobs` added to its jobs."""
    text = LEGAL[: LEGAL.index("applications:")] + "applications:\n" + apps
    if jobs:
        text = changed("jobs:\n", "jobs:\n" + jobs, text)
    return text


Q = "[0, -0.5, 0.5, 0, 0, 0]"
TRAJ2 = "  traj2: {module: fake_traj, rtpu: rtpu0, period: 2 ms}\n"
BOTH_WRITER_AND_READER = (
    ("variables:\n", "variables:\n  c: {type: float64}\n"),
    ("tasks:\n", "tasks:\n  w: {module: fake_both_writer, rtpu: rtpu0, period: 1 ms}\n"
                 "  r: {module: fake_both_reader, rtpu: rtpu0, period: 1 ms}\n"),
)


# --- one mistake, one message ----------------------------------------------------------------


def mistake(name: str, text: str, needle: str, message: str, *, nth: int = 0, code: str = r"E\d{3}",
            hint: str | None = None):
    """A file with one mistake: its one error is at the `nth` `needle`, its message matches `message`
    (anchored after location and code), and its hint, if given, is searched for `hint` (both regexes)."""
    return pytest.param(text, needle, message, nth, code, hint, id=name)


ONE_MISTAKE = [
    # keys and types
    mistake("an_unknown_key_in_a_task_is_an_error_with_a_suggestion",
            changed("critical: true", "critcal: true"), "critcal", r"unknown key 'critcal' in task 'robot'$",
            hint=r"did you mean 'critical'\?"),
    mistake("an_unknown_key_in_a_variable_is_an_error",
            changed("q_r:   {type: float64,", "q_r:   {type: float64, units: rad,"), "units",
            r"unknown key 'units' in variable 'q_r'$"),
    mistake("a_misspelt_required_key_is_one_error_not_two",
            changed("module: fake_robot", "modul: fake_robot"), "modul:",
            r"unknown key 'modul' in task 'robot': did you mean the required key 'module'\?$"),
    mistake("a_task_without_a_module_is_an_error_at_the_task",
            changed("module: fake_traj, ", ""), "traj:", r"task 'traj' has no 'module:', which is required$"),
    mistake("a_flag_that_is_not_a_boolean_is_an_error",
            changed("critical: true", "critical: yes please"), "yes please",
            r"'critical' of task 'robot' must be true or false, got: the text 'yes please'$"),
    mistake("an_invalid_subsystem_name_is_an_error",
            changed("subsystem: puma", "subsystem: my puma/1"), "my puma",
            r"subsystem name 'my puma/1' is not usable in shared-memory names$"),
    mistake("an_rtpu_cpu_must_be_a_non_negative_integer",
            changed("rtpus: [rtpu0, rtpu1]", "rtpus: {rtpu0: {cpu: -1}, rtpu1: {cpu: 1}}"), "-1",
            r"cpu of RTPU 'rtpu0' must be >= 0, got: -1$"),
    mistake("an_rtpu_spin_as_long_as_its_shortest_period_is_an_error",
            changed("rtpus: [rtpu0, rtpu1]", "rtpus: {rtpu0: {spin: 1 ms}, rtpu1: null}"), "1 ms}",
            r"spin of RTPU 'rtpu0' must be shorter than the shortest period of its tasks \(1 ms, task 'pid'\), got: 1 ms$",
            code="E509"),
    # undefined names
    mistake("a_port_linked_to_an_undefined_variable_is_an_error_with_a_suggestion",
            changed("ports: {tau: tau_u}", "ports: {tau: tau_uu}"), "tau_uu",
            r"task 'pid' links port 'tau' to variable 'tau_uu', which 'variables' does not declare$",
            hint=r"^did you mean 'tau_u'\?"),
    mistake("a_port_of_any_dtype_linked_by_default_to_an_undeclared_variable_is_an_error",
            edited(("  pid: ", "  kr:    {module: fake_k_reader, rtpu: rtpu0, period: 1 ms}\n  pid: "),
                   ("[robot, traj, pid]", "[robot, traj, pid, kr]")), "kr:",
            r"task 'kr' \(module 'fake_k_reader'\) links port 'k' by default to variable 'K', which 'variables' does not declare "
            r"and its ports cannot define$",
            hint=r"^no port that links 'K' declares a dtype \(port 'k' of task 'kr' is any dtype, any shape\); declare 'K' "
                 r"under variables: .*ports: \{k: <variable>\}"),
    mistake("an_unknown_module_is_an_error_with_a_suggestion",
            changed("module: fake_traj", "module: fake_trajj"), "fake_trajj",
            r"task 'traj' uses module 'fake_trajj', which is not registered$",
            hint=r"^did you mean 'fake_traj'\? \(registered: "),
    mistake("an_unknown_rtpu_is_an_error_with_a_suggestion",
            changed("rtpu: rtpu1", "rtpu: rtpu2"), "rtpu2", r"task 'robot' runs on RTPU 'rtpu2', which 'rtpus' does not declare$",
            hint=r"^did you mean 'rtpu[01]'\? \(declared: rtpu0, rtpu1\)$"),
    mistake("an_unknown_device_is_an_error",
            changed("resources: [arm]", "resources: [army]"), "army",
            r"task 'robot' uses device 'army', which 'devices' does not declare$"),
    mistake("an_unknown_dim_in_a_shape_is_an_error",
            changed("q_d:   {type: float64, shape: [NDOF]", "q_d:   {type: float64, shape: [NDFO]"), "NDFO",
            r"shape of variable 'q_d' uses dim 'NDFO', which 'dims' does not define$",
            hint=r"did you mean 'NDOF'\?"),
    mistake("an_unknown_task_in_a_configuration_is_an_error",
            changed("[robot, traj, pid]", "[robot, traj, pid, gravity]"), "gravity",
            r"configuration 'joint_pid' names task 'gravity', which 'tasks' does not declare$"),
    mistake("an_unknown_configuration_in_a_job_is_an_error",
            changed("configuration: joint_pid", "configuration: joint_pd"), "joint_pd,",
            r"job 'move' runs configuration 'joint_pd', which 'configurations' does not declare$",
            hint=r"^did you mean 'joint_pid'\?"),
    mistake("a_port_the_module_does_not_declare_is_an_error",
            changed("ports: {tau: tau_u}", "ports: {tau: tau_u, torque: tau_u}"), "torque",
            r"module 'fake_pid' of task 'pid' has no port 'torque'$",
            hint=r"^\(ports: ndof, q_m, q_r, tau\)$"),
    # ports and variables agree
    mistake("a_port_and_its_variable_must_have_the_same_dtype_reported_at_the_declaration_its_ports_agree_against",
            changed("q_d:   {type: float64", "q_d:   {type: float32"), "float32",
            r"variable 'q_d' is float32, but the one port that links it is float64$", code="E301",
            hint=r"^change the type of 'q_d' to float64$"),
    mistake("an_unknown_dtype_is_an_error_with_the_valid_ones",
            changed("q_d:   {type: float64", "q_d:   {type: float46"), "float46", r"variable 'q_d' has unknown type 'float46'$",
            hint=r"^did you mean 'float64'\? \(valid: bool, float32, float64, int16, int32, int64, int8, uint16, uint32, "
                 r"uint64, uint8\)"),
    # producers and consumers
    mistake("in_both_whose_writer_the_configuration_leaves_out_is_an_error_at_the_configuration",
            edited(*BOTH_WRITER_AND_READER, ("configurations:\n", "configurations:\n  both: [r]\n  other: [w]\n")),
            "[r]", r"configuration 'both' leaves out task 'w', which writes 'c', read by 'r'$", code="E408",
            hint=r"^add it: both: \[r, w\]$"),
    mistake("a_task_appears_at_most_once_in_a_configuration",
            changed("[robot, traj, pid]", "[robot, traj, pid, traj]"), "traj",
            r"task 'traj' appears twice in configuration 'joint_pid' \(first at line 17, column 22\)$", nth=3,
            hint=r"declare a second task"),
    # periods
    mistake("a_period_must_be_positive",
            changed("period: 2 ms", "period: -5 ms"), "-5 ms", r"period of task 'traj' must be > 0, got: -5 ms$"),
    mistake("a_rate_must_be_positive",
            changed("rate: 1 kHz", "rate: 0 Hz"), "0 Hz", r"rate of task 'pid' must be > 0, got: 0 Hz$"),
    mistake("a_task_cannot_give_both_period_and_rate",
            changed("rate: 1 kHz", "rate: 1 kHz, period: 1 ms"), "rate:", r"task 'pid' gives both a period and a rate$"),
    mistake("a_task_needs_a_period_or_a_rate",
            changed(", period: 2 ms", ""), "traj:", r"task 'traj' needs a period or a rate$"),
    mistake("a_period_in_frequency_units_says_to_use_rate",
            changed("period: 2 ms", "period: 500 Hz"), "500 Hz",
            r"period of task 'traj': expected a time like '1 ms' or a number of seconds, got: '500 Hz' \(that is a frequency\)$",
            hint=r"rate: 1 kHz"),
    # devices
    mistake("an_exclusive_device_has_one_user_per_configuration",
            changed("period: 2 ms}", "period: 2 ms, resources: [arm]}"), "arm",
            r"device 'arm' is exclusive, but configuration 'joint_pid' gives it to 'robot' \(line 13\) and 'traj'", nth=3,
            hint=r"exclusive: false"),
    # values
    mistake("an_initial_value_must_match_the_shape",
            changed("q_m:   {type: float64, shape: [NDOF]}", "q_m:   {type: float64, shape: [NDOF], initial: [1, 2, 3]}"),
            "[1, 2, 3]", r"initial value of variable 'q_m' has shape \(3,\), but the variable's shape is \(6,\)$"),
    mistake("an_initial_value_must_fit_the_dtype",
            changed("initial: 6}", "initial: 6.5}"), "6.5",
            r"initial value of variable 'NDOF': int32 elements must be integers, got: the number 6.5$"),
    mistake("params_the_module_refuses_are_an_error_at_the_parameter_it_names",
            changed("params: {kp: 400}", "params: {kp: 400, ki: 1}"), "ki: 1",
            r"params of task 'pid' \(module 'fake_pid'\): unknown parameter\(s\) 'ki' for FakePid \(valid: kd, kp\)$"),
    mistake("a_misspelt_parameter_is_answered_with_the_closest_one",
            changed("params: {kp: 400}", "params: {kpp: 400}"), "kpp: 400",
            r"params of task 'pid' \(module 'fake_pid'\): unknown parameter\(s\) 'kpp' for FakePid; "
            r"did you mean 'kp'\? \(valid: kd, kp\)$"),
    mistake("missing_params_are_an_error",
            changed(", params: {kp: 400}", ""), "pid:",
            r"params of task 'pid' \(module 'fake_pid'\): missing parameter\(s\) 'kp'"),
    *[mistake(f"a_parameter_out_of_its_range_is_an_error_at_its_value_naming_the_range_{name}",
              changed("params: {kp: 400}", f"params: {{kp: {value}}}"), str(value),
              rf"parameter kp of task 'pid' \(module 'fake_pid'\) must be in \[0, 1e\+06\], got: {shown}$",
              code="E308", hint=r"^module 'fake_pid' declares this range")
      for name, value, shown in [("nan", ".nan", r"\.nan \(not a number\)"), ("inf", ".inf", r"\.inf"),
                                 ("huge", "1.0e+308", r"1e\+308"), ("negative", "-1", "-1")]],
    mistake("a_list_parameter_out_of_its_range_is_an_error_at_the_element",
            changed("params: {kp: 400}", "params: {kp: [1, 2, 3, .nan, 5, 6]}"), ".nan",
            r"parameter kp\[3\] of task 'pid' \(module 'fake_pid'\) must be in \[0, 1e\+06\], got: \.nan \(not a number\)$",
            code="E308"),
    mistake("a_number_parameter_without_a_range_is_still_finite",
            changed("params: {kp: 400}", "params: {kp: 400, kd: -.inf}"), "-.inf",
            r"parameter kd of task 'pid' \(module 'fake_pid'\) must be a finite number, got: -\.inf$",
            code="E308", hint=r"finite numbers only"),
    # an object type's range
    mistake("an_object_types_range_must_be_two_numbers_low_first",
            changed("variables:\n",
                    "object_types:\n  joint_position: {type: float64, shape: [NDOF], range: [3, -3]}\nvariables:\n"),
            "[3, -3]", r"range of object type 'joint_position' must be \[low, high\], two finite numbers with low < high, "
                       r"got: \[3, -3\]$", code="E321"),
    mistake("an_applications_object_outside_its_types_range_is_an_error_at_the_element",
            edited(("variables:\n",
                    "object_types:\n  joint_position: {type: float64, shape: [NDOF], range: [-0.4, 0.4]}\nvariables:\n")),
            "-0.5",
            r"object 'q_d' of step 1 of application 'demo': element 2 must be in \[-0\.4, 0\.4\] \(the range of object type "
            r"'joint_position'\), got: -0\.5$", code="E322", hint=r"^object type 'joint_position' declares this range"),
    # bounds of names and times
    mistake("a_subsystem_name_of_300_characters_is_an_error",
            changed("subsystem: puma", "subsystem: " + "p" * 300), "ppp",
            r"subsystem name 'p{30}\.\.\.p{10}' is 300 characters long, more than the 40 a name may have$", code="E218"),
    mistake("a_variable_name_of_41_characters_is_an_error_at_the_name",
            changed("variables:\n", "variables:\n  " + "v" * 41 + ": {type: float64, initial: 0}\n"), "v" * 41,
            rf"variable name '{'v' * 41}' is 41 characters long, more than the 40 a name may have$", code="E218"),
    mistake("a_period_of_1e300_s_is_an_error",
            changed("period: 2 ms", "period: 1e300 s"), "1e300 s",
            r"period of task 'traj' must be between 10 us and 1 h, got: 1e300 s$", code="E513"),
    mistake("a_period_of_a_microsecond_is_an_error",
            changed("period: 2 ms", "period: 1 us"), "1 us",
            r"period of task 'traj' must be between 10 us and 1 h, got: 1 us$", code="E513"),
    mistake("a_rate_of_1e_minus_300_hz_is_an_error",
            changed("rate: 1 kHz", "rate: 1e-300 Hz"), "1e-300 Hz",
            r"rate of task 'pid' must be between one cycle an hour and 100 kHz, got: 1e-300 Hz$", code="E513"),
    mistake("a_job_timeout_of_a_year_is_an_error",
            changed("timeout: 10 s", "timeout: 31536000 s"), "31536000 s",
            r"timeout of job 'move' must be at most a day \(86,400 s\), got: 31536000 s$", code="E513"),
    # jobs and applications
    mistake("a_job_object_must_be_a_variable_marked_as_an_object",
            changed("object: q_d, post", "object: q_m, post"), "q_m, post",
            r"job 'move' takes variable 'q_m' as its object, but the variable is not marked as an object$"),
    mistake("a_job_condition_must_be_an_expression",
            changed('"max(abs(q_m - q_d)) < 1e-3"', '"max(abs(q_m - q_d) < 1e-3"'), "(abs",
            r"post-condition of job 'move' is not an expression: '\(' was never closed: "),
    mistake("an_application_step_must_name_a_job",
            changed("- move:", "- mvoe:"), "mvoe",
            r"step 1 of application 'demo' runs job 'mvoe', which 'jobs' does not declare$",
            hint=r"^did you mean 'move'\?"),
    mistake("an_application_object_must_match_the_variable_shape",
            changed("[0, -0.5, 0.5, 0, 0, 0]", "[0, -0.5, 0.5]"), "[0, -0.5, 0.5]",
            r"object 'q_d' of step 1 of application 'demo' has shape \(3,\), but the variable's shape is \(6,\)$"),
    # issue 18: non-finite values, at the value itself
    mistake("an_initial_value_may_not_be_nan",
            changed("tau_u: {type: float64, shape: [NDOF]}",
                    "tau_u: {type: float64, shape: [NDOF], initial: [0, 0, .nan, 0, 0, 0]}"),
            ".nan", r"initial value of variable 'tau_u': float64 elements must be finite numbers, got: \.nan \(not a number\)$",
            code="E314", hint=r"^write a finite number; NaN and Inf would travel on to the actuators$"),
    mistake("a_scalar_initial_value_may_not_be_infinite",
            changed("q_m:   {type: float64, shape: [NDOF]}", "q_m:   {type: float64, shape: [NDOF], initial: -.inf}"),
            "-.inf", r"initial value of variable 'q_m': float64 elements must be finite numbers, got: -\.inf$", code="E314"),
    mistake("an_application_object_may_not_be_infinite",
            changed("[0, -0.5, 0.5, 0, 0, 0]", "[0, -0.5, 0.5, 0, .Inf, 0]"), ".Inf",
            r"object 'q_d' of step 1 of application 'demo': float64 elements must be finite numbers, got: \.inf$", code="E314"),
    mistake("a_nested_initial_value_is_refused_at_the_element",
            edited(("variables:\n", "variables:\n  K: {type: float32, shape: [2, 2], initial: [[1, 2], [.NaN, 4]]}\n"),
                   ("  pid:   {", "  k:     {module: fake_k_reader, rtpu: rtpu0, period: 1 ms}\n  pid:   {"),
                   ("[robot, traj, pid]", "[robot, traj, pid, k]")),
            ".NaN", r"initial value of variable 'K': float32 elements must be finite numbers, got: \.nan \(not a number\)$",
            code="E314"),
    # issue 18: sizes bounded before anything is built
    mistake("a_dim_beyond_the_limit_is_an_error_at_the_dim_and_nowhere_else",
            changed("NDOF: 6}", "NDOF: 1000000000000}"), "1000000000000",
            r"dim 'NDOF' must be at most 16,777,216, got: 1,000,000,000,000$", code="E315",
            hint=r"is a digit too many\?$"),
    mistake("a_dim_that_is_a_float_is_an_error_at_the_dim_and_nowhere_else",
            changed("NDOF: 6}", "NDOF: 1.0e+12}"), "1.0e+12", r"dim 'NDOF' must be an integer, got: the number 1000000000000\.0$",
            code="E116"),
    mistake("a_size_in_a_shape_beyond_the_limit_is_an_error_at_the_size",
            edited(("variables:\n", "variables:\n  K: {type: float32, shape: [2, 100000000], initial: 0}\n"),
                   ("  pid:   {", "  k:     {module: fake_k_reader, rtpu: rtpu0, period: 1 ms}\n  pid:   {"),
                   ("[robot, traj, pid]", "[robot, traj, pid, k]")),
            "100000000", r"shape of variable 'K': each size must be at most 16,777,216, got: 100,000,000$", code="E315"),
    mistake("a_variable_larger_than_the_table_is_an_error_at_its_shape_before_its_initial_value_is_built",
            edited(("variables:\n", "variables:\n  K: {type: float64, shape: [4096, 4096], initial: 0}\n"),
                   ("  pid:   {", "  k:     {module: fake_k_reader, rtpu: rtpu0, period: 1 ms}\n  pid:   {"),
                   ("[robot, traj, pid]", "[robot, traj, pid, k]")),
            "[4096, 4096]", r"variable 'K' \(float64, shape \(4096, 4096\)\) would take 134,217,728 bytes \(128 MiB\), more than "
                    r"the whole state variable table may hold, 67,108,864 bytes \(64 MiB\)$", code="E315"),
    mistake("variables_that_together_exceed_the_table_are_an_error_at_variables",  # (unread: warnings only)
            changed("variables:\n",
                    "variables:\n  K: {type: float64, shape: [2100, 2100]}\n  L: {type: float64, shape: [2100, 2100]}\n"),
            "variables:", r"the variables take 70,560,\d+ bytes \(67.3 MiB\) of state variable table, more than its limit of "
                  r"67,108,864 bytes \(64 MiB\)$", code="E316", hint=r"^the largest: '[KL]' \(2100, 2100\) float64"),
    # issue 18: integers in conditions are bounded, never wrapped
    mistake("a_condition_may_not_compute_an_integer_beyond_int64",
            changed('"max(abs(q_m - q_d)) < 1e-3"', '"10**10**10 > 1"'), "10**10**10",
            r"post-condition of job 'move': the integer 10\*\*10\*\*10 is beyond the integers a condition computes with "
            r"\(at most 9,223,372,036,854,775,807 = 2\*\*63 - 1\) \(column 1 of '10\*\*10\*\*10 > 1'\)$", code="E710",
            hint=r"write a float \(1e30\)"),
    mistake("a_condition_may_not_write_an_integer_beyond_int64",
            changed('"max(abs(q_m - q_d)) < 1e-3"', '"max(abs(q_m)) < 99999999999999999999"'), "99999999999999999999",
            r"post-condition of job 'move': the integer 99999999999999999999 is beyond the integers", code="E710"),
    mistake("a_product_of_written_integers_beyond_int64_is_refused",
            changed('"max(abs(q_m - q_d)) < 1e-3"', '"max(abs(q_m)) < 3037000500 * 3037000500"'), "3037000500 *",
            r"post-condition of job 'move': the integer 3037000500 \* 3037000500 is beyond", code="E710"),
    # task names and modules
    mistake("a_module_runs_at_most_once_in_a_configuration",
            edited(("configurations:\n", TRAJ2 + "configurations:\n"), ("[robot, traj, pid]", "[robot, traj, pid, traj2]")),
            "traj2]", r"configuration 'joint_pid' runs module 'fake_traj' twice: as task 'traj' \(line 14\) and as task 'traj2' "
              r"\(line 16\), both writing q_r$", code="E407",
            hint=r"declare 'q_r_traj2' under variables:, link them with ports: \{q_r: q_r_traj2\}\) and join each"),
    # job conditions
    mistake("a_condition_may_not_access_attributes_and_says_where",
            changed('"max(abs(q_m - q_d)) < 1e-3"', '"q_m.max() < 1e-3"'), "q_m.max",
            r"post-condition of job 'move': attribute access \('\.max'\) is not allowed in a condition "
            r"\(column 1 of 'q_m\.max\(\) < 1e-3'\)$", code="E703",
            hint=r"abs, max, min, sum, all, any, norm, sqrt"),
    mistake("a_condition_may_not_import",
            changed('"max(abs(q_m - q_d)) < 1e-3"', "\"__import__('os').system('true') == 0\""), "__import__",
            r"post-condition of job 'move': attribute access \('\.system'\) is not allowed", code="E703"),
    mistake("a_condition_names_only_declared_variables",
            changed('"max(abs(q_m - q_d)) < 1e-3"', '"max(abs(q_x - q_d)) < 1e-3"'), "q_x",
            r"post-condition of job 'move' uses 'q_x', which 'variables' does not declare$", code="E704",
            hint=r"^did you mean"),
    # applications
    mistake("an_object_given_to_a_job_that_takes_none_is_an_error",
            with_apps(f"  demo:\n    - hold: {{q_d: {Q}}}\n", "  hold: {configuration: joint_pid, object: none}\n"), "q_d: [0",
            r"step 1 of application 'demo' gives object 'q_d' to job 'hold', which takes no object$", code="E705"),
    mistake("two_objects_for_one_job_are_an_error",
            with_apps(f"  demo:\n    - move: {{q_d: {Q}, q_r: {Q}}}\n"), "q_r: [0",
            r"step 1 of application 'demo' gives 2 objects to job 'move' \(q_d, q_r\), but a job takes exactly one$",
            code="E706"),
    mistake("an_object_that_is_not_the_jobs_is_an_error",
            with_apps(f"  demo:\n    - move: {{q_m: {Q}}}\n"), "q_m: [0",
            r"step 1 of application 'demo' gives 'q_m' to job 'move', but its object is 'q_d' \(type joint_position\)$",
            code="E707"),
    mistake("an_application_step_takes_no_objects",
            with_apps(f"  demo: [{{move: {{q_d: {Q}}}}}]\n  outer:\n    - demo: {{q_d: {Q}}}\n"), "{q_d",
            r"step 1 of application 'outer' gives objects to application 'demo', which takes none$", nth=1, code="E709"),
    mistake("a_job_and_an_application_may_not_share_a_name",
            with_apps(f"  move: [{{move: {{q_d: {Q}}}}}]\n"), "move: [",
            r"'move' names both a job and an application$", code="E214"),
    # timing
    mistake("a_wcet_longer_than_the_period_is_an_error",
            changed("period: 2 ms}", "period: 2 ms, wcet: 3 ms}"), "3 ms",
            r"wcet of task 'traj' must be <= its period \(2 ms\), got: 3 ms$", code="E505"),
    mistake("a_wcet_must_be_positive",
            changed("period: 2 ms}", "period: 2 ms, wcet: 0 ms}"), "0 ms",
            r"wcet of task 'traj' must be > 0, got: 0 ms$", code="E502"),
    # aperiodic tasks
    mistake("an_aperiodic_task_takes_no_period",
            changed("period: 2 ms}", "aperiodic: true, min_interarrival: 5 ms, period: 2 ms}"), "period: 2 ms}",
            r"task 'traj' is aperiodic, so it takes no period$", code="E506"),
    mistake("an_aperiodic_task_takes_no_rate",
            changed("rate: 1 kHz", "rate: 1 kHz, aperiodic: true, min_interarrival: 5 ms"), "rate:",
            r"task 'pid' is aperiodic, so it takes no rate$", code="E506"),
    mistake("an_aperiodic_task_needs_a_min_interarrival",
            changed("period: 2 ms}", "aperiodic: true}"), "aperiodic",
            r"aperiodic task 'traj' needs a min_interarrival$", code="E507"),
    mistake("a_min_interarrival_must_be_positive",
            changed("period: 2 ms}", "aperiodic: true, min_interarrival: 0 s}"), "0 s}",
            r"min_interarrival of task 'traj' must be > 0, got: 0 s$", code="E502"),
    mistake("a_periodic_task_takes_no_min_interarrival",
            changed("period: 2 ms}", "period: 2 ms, min_interarrival: 5 ms}"), "min_interarrival",
            r"task 'traj' gives a min_interarrival but is not aperiodic$", code="E508"),
]


@pytest.mark.parametrize(("text", "needle", "message", "nth", "code", "hint"), ONE_MISTAKE)
def test_one_mistake_is_one_error_at_its_node_with_an_anchored_message(tmp_path: Path, text: str, needle: str, message: str,
                                                                        nth: int, code: str, hint: str | None) -> None:
    error = expect_error(tmp_path, text, needle, message, nth=nth, code=code)
    if hint is not None:
        assert re.search(hint, error.hint), error.hint


# --- the legal file ------------------------------------------------------------------------


def test_the_legal_file_has_no_error_and_no_warning(tmp_path: Path) -> None:
    result = check(tmp_path, LEGAL)
    assert result.errors == []
    assert result.warnings == []
    assert result.subsystem is not None


@pytest.mark.parametrize(("plant", "codes"), [
    ("{type: not_a_robot_plant, model: none}", []),  # not a robot plant: its model is its own business
    ("{model: none}", ["E216"]),  # the default plant (mujoco_arm) simulates robots
])
def test_only_a_plant_that_simulates_robots_needs_a_robot_for_its_model(tmp_path: Path, plant: str, codes: list[str]) -> None:
    result = check(tmp_path, changed("dims: {NDOF: 6}", f"plant: {plant}\ndims: {{NDOF: 6}}"))
    assert [e.code for e in result.errors] == codes, result.errors


# --- keys and types ------------------------------------------------------------------------


def test_an_unknown_top_level_key_is_an_error_with_a_suggestion(tmp_path: Path) -> None:
    text = changed("dims:", "dimz:")
    error = check(tmp_path, text).errors[0]
    assert (error.line, error.column) == at(text, "dimz")
    assert re.match(r"^unknown key 'dimz' at the top level$", error.message)
    assert error.hint.startswith("did you mean 'dims'?")


def test_a_missing_required_top_level_key_is_an_error(tmp_path: Path) -> None:
    text = changed("rtpus: [rtpu0, rtpu1]\n", "")
    result = check(tmp_path, text)
    assert any(re.match(r"^the file has no 'rtpus:', which is required$", e.message) for e in result.errors)


def test_a_section_of_the_wrong_type_is_an_error(tmp_path: Path) -> None:
    text = changed("dims: {NDOF: 6}", "dims: 6")
    result = check(tmp_path, text)
    error = result.errors[0]
    assert re.match(r"^'dims' must be a mapping, got: the integer 6$", error.message)
    assert (error.line, error.column) == at(text, "6", 0)


def test_rtpus_may_be_a_mapping_with_cpus(tmp_path: Path) -> None:
    result = check(tmp_path, changed("rtpus: [rtpu0, rtpu1]", "rtpus: {rtpu0: {cpu: 0}, rtpu1: {cpu: 1}}"))
    assert result.errors == []
    assert result.subsystem is not None
    assert [(r.name, r.index, r.cpu) for r in result.subsystem.rtpus] == [("rtpu0", 0, 0), ("rtpu1", 1, 1)]


def test_an_rtpu_spins_200_us_before_a_release_unless_it_gives_its_own_spin(tmp_path: Path) -> None:
    result = check(tmp_path, changed("rtpus: [rtpu0, rtpu1]", "rtpus: {rtpu0: {spin: 50 us}, rtpu1: null}"))
    assert result.errors == [] and result.subsystem is not None
    assert [(r.name, r.spin) for r in result.subsystem.rtpus] == [("rtpu0", pytest.approx(50e-6)), ("rtpu1", 0.0002)]


@pytest.mark.parametrize(("rtpus", "policies"), [
    ("rtpus: [rtpu0, rtpu1]", [None, None]),  # the default: an RTPU's death stops the run
    ("rtpus: [rtpu0, rtpu1]\nrestart: {max: 3, within: 10 s}", [(3, 10.0), (3, 10.0)]),
    ("rtpus: {rtpu0: {restart: {max: 2, within: 500 ms}}, rtpu1: null}", [(2, 0.5), None]),
    ("rtpus: {rtpu0: {restart: {max: 0}}, rtpu1: {}}\nrestart: {max: 3, within: 10 s}", [None, (3, 10.0)]),
])
def test_an_rtpus_restart_policy_is_its_own_or_the_subsystems(tmp_path: Path, rtpus: str, policies: list) -> None:
    result = check(tmp_path, changed("rtpus: [rtpu0, rtpu1]", rtpus))
    assert result.errors == [] and result.subsystem is not None
    found = [(r.restart.max, r.restart.within) if r.restart else None for r in result.subsystem.rtpus]
    assert found == policies


@pytest.mark.parametrize(("restart", "needle", "message"), [
    ("restart: {max: 3}", "{max: 3}", r"the restart of the subsystem has no 'within:', which is required"),
    ("restart: {max: three, within: 1 s}", "three", r"max of the restart of the subsystem must be an integer"),
    ("restart: {max: -1, within: 1 s}", "-1", r"max of the restart of the subsystem must be >= 0"),
    ("restart: {max: 3, within: 1 kHz}", "1 kHz", r"within of the restart of the subsystem"),
    ("restart: {max: 3, witin: 1 s}", "witin", r"unknown key 'witin' in the restart of the subsystem: did you mean"),
    ("restart: 3", "3", r"restart of the subsystem must be a mapping"),
])
def test_a_wrong_restart_policy_is_one_error_at_its_value(tmp_path: Path, restart: str, needle: str, message: str) -> None:
    text = changed("rtpus: [rtpu0, rtpu1]", f"rtpus: [rtpu0, rtpu1]\n{restart}")
    error = only_error(check(tmp_path, text))
    line = text.splitlines().index(restart) + 1
    assert (error.line, error.column) == (line, restart.index(needle) + 1), str(error)
    assert re.match(message, error.message), str(error)


# --- undefined names -----------------------------------------------------------------------


def test_a_port_shape_naming_an_undefined_dim_is_an_error(tmp_path: Path) -> None:
    text = changed("  demo:\n", "  demo:\n", LEGAL)
    text = changed("tasks:\n", "tasks:\n  needs: {module: fake_needs_dim, rtpu: rtpu0, period: 1 ms}\n", text)
    text = changed("q_d:   {", "x: {type: float64, shape: [3]}\n  q_d:   {", text)
    text = changed("[robot, traj, pid]", "[robot, traj, pid, needs]", text)
    result = check(tmp_path, text)
    error = only_error(result)
    assert re.match(r"^port 'x' of module 'fake_needs_dim' \(task 'needs'\) has shape \(NJOINTS,\) with dim 'NJOINTS'",
                    error.message)


# --- ports and variables agree ---------------------------------------------------------------


def test_a_port_and_its_variable_must_have_the_same_resolved_shape(tmp_path: Path) -> None:
    text = changed("q_r:   {type: float64, shape: [NDOF]}", "q_r:   {type: float64, shape: [7]}")
    error = expect_error(tmp_path, text, "[7]",
                         r"variable 'q_r' has shape \(7,\), but all 2 ports that link it are of shape \(6,\)$",
                         code="E302")
    assert error.hint == "change the shape of 'q_r' to [NDOF]"
    assert [(n.line, n.message) for n in error.notes] == [  # traj writes it, pid reads it
        (at(text, "traj:")[0], "task 'traj' port 'q_r' (out-var) has shape (6,) = (NDOF,)"),
        (at(text, "pid:")[0], "task 'pid' port 'q_r' (in-var) has shape (6,) = (NDOF,)")]


# --- producers and consumers -----------------------------------------------------------------


def test_an_input_nobody_writes_is_an_error_naming_the_configuration(tmp_path: Path) -> None:
    text = edited(("ports: {tau: tau_u}", "ports: {tau: tau_u, q_r: q_x}"),
                  ("  tau_u:", "  q_x:   {type: float64, shape: [NDOF]}\n  tau_u:"))
    error = expect_error(tmp_path, text, "q_x}",
                         r"task 'pid' reads in-var 'q_x', but no task in configuration 'joint_pid' writes it$",
                         code="E403")
    assert "written: " in error.hint


def test_a_task_the_configuration_leaves_out_is_reported_at_its_list_with_the_readers_as_notes(tmp_path: Path) -> None:
    text = changed("[robot, traj, pid]", "[robot, pid]")
    error = expect_error(tmp_path, text, "[robot, pid]",
                         r"configuration 'joint_pid' leaves out task 'traj', which writes 'q_r', read by 'pid'$", code="E408")
    assert error.hint == "add it: joint_pid: [robot, pid, traj]"
    assert [(n.line, n.message) for n in error.notes] == [(at(text, "pid:")[0], "task 'pid' reads in-var 'q_r'"),
                                                          (at(text, "traj:")[0], "task 'traj' writes 'q_r'")]


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
        rf"^.*bad\.yaml:{line}:{column}: error\[E401\]: variable 'tau_u' has two writers in configuration 'joint_pid': "
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
        rf"^.*bad\.yaml:{line}:{column}: error\[E404\]: task 'robot' reads in-const 'NDOF' before its init, "
        r"but its writer 'dims' in configuration 'joint_pid' writes it as out-var \(only after each cycle\)",
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
    assert re.match(r"^task 'robot' reads in-const 'NDOF' before its init, but in configuration 'joint_pid' only job control",
                    result.errors[0].message)


def test_in_both_takes_an_out_both(tmp_path: Path) -> None:
    text = changed("variables:\n", "variables:\n  c: {type: float64}\n")
    text = changed("tasks:\n",
                   "tasks:\n  w: {module: fake_both_writer, rtpu: rtpu0, period: 1 ms}\n"
                   "  r: {module: fake_both_reader, rtpu: rtpu0, period: 1 ms}\n", text)
    text = changed("configurations:\n", "configurations:\n  both: [w, r]\n", text)
    assert check(tmp_path, text).errors == []


def test_a_cycle_of_const_dependencies_is_an_error_that_prints_the_cycle(tmp_path: Path) -> None:
    text = changed("variables:\n", "variables:\n  a: {type: float64}\n  b: {type: float64}\n")
    text = changed("tasks:\n",
                   "tasks:\n  ta: {module: fake_const_a, rtpu: rtpu0, period: 1 ms}\n"
                   "  tb: {module: fake_const_b, rtpu: rtpu0, period: 1 ms}\n", text)
    text = changed("configurations:\n", "configurations:\n  consts: [ta, tb]\n", text)
    error = only_error(check(tmp_path, text))
    assert re.match(r"^const dependencies form a cycle: (ta -> tb -> ta|tb -> ta -> tb)$", error.message)
    assert error.code == "E406"
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


def test_a_rate_becomes_a_period(tmp_path: Path) -> None:
    result = check(tmp_path, LEGAL)
    assert result.subsystem is not None
    assert result.subsystem.tasks["pid"].period == pytest.approx(1e-3)


# --- devices ---------------------------------------------------------------------------------


def test_a_shared_device_may_have_many_users(tmp_path: Path) -> None:
    text = changed("exclusive: true", "exclusive: false")
    text = changed("period: 2 ms}", "period: 2 ms, resources: [arm]}", text)
    assert check(tmp_path, text).errors == []


# --- values ----------------------------------------------------------------------------------


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


def test_a_module_that_cannot_list_its_ports_is_reported_not_raised(tmp_path: Path) -> None:
    text = changed("module: fake_traj", "module: fake_broken")
    result = check(tmp_path, text)
    assert any(re.match(r"^module 'fake_broken' of task 'traj' cannot list its ports: RuntimeError", e.message)
               and e.code == "E307" for e in result.errors)


class FakeBadShape(PortBasedObject):
    x = InVar("q_m", shape=(None,))  # type: ignore[arg-type]  # a module bug on purpose


def test_a_module_with_a_malformed_port_shape_is_reported_not_raised(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(FAKES, "fake_bad_shape", FakeBadShape)
    text = changed("module: fake_traj", "module: fake_bad_shape")
    codes = {e.code for e in check(tmp_path, text).errors}
    assert "E306" in codes, codes


def test_a_bug_in_the_checker_is_an_internal_error_not_a_traceback(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from pbo_runtime.config import checker

    def broken(self: Any) -> None:
        raise RuntimeError("boom")

    monkeypatch.setattr(checker._Checker, "check_unused", broken)
    error = only_error(check(tmp_path, LEGAL))
    assert error.code == "E901" and re.match(r"^internal error in the checker: RuntimeError\('boom'\)$", error.message)


# --- jobs and applications ------------------------------------------------------------------


def test_an_application_step_without_its_object_is_only_a_warning_and_makes_it_incomplete(tmp_path: Path) -> None:
    text = changed("    - move: {q_d: [0, -0.5, 0.5, 0, 0, 0]}", "    - move: {q_d: [0, -0.5, 0.5, 0, 0, 0]}\n    - move")
    result = check(tmp_path, text)
    assert result.errors == []
    [warning] = result.warnings
    line, column = at(text, "move", 2)
    assert re.match(
        rf"^.*bad\.yaml:{line}:{column}: warning\[W701\]: application 'demo' is incomplete: "
        r"step 2 'move' needs an object of type joint_position$",
        str(warning), re.MULTILINE,
    ), str(warning)
    assert result.subsystem is not None and result.subsystem.applications["demo"].complete is False


# --- warnings ------------------------------------------------------------------------------


def test_a_variable_nobody_reads_is_a_warning(tmp_path: Path) -> None:
    text = changed("variables:\n", "variables:\n  spare: {type: float64}\n")
    result = check(tmp_path, text)
    assert result.errors == []
    [warning] = result.warnings
    line, column = at(text, "spare")
    assert str(warning) == (f"{tmp_path / 'bad.yaml'}:{line}:{column}: warning[W202]: variable 'spare' is read by no task\n"
                            "  hint: remove it, or link a task's input port to it")


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


# --- codes -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("code", "old", "new", "needle", "message"),
    [
        ("E111", "critical: true", "critcal: true", "critcal", r"unknown key 'critcal' in task 'robot'$"),
        ("E112", "module: fake_traj, ", "", "traj:", r"task 'traj' has no 'module:', which is required$"),
        ("E115", "critical: true", "critical: 1", "1, resources",
         r"'critical' of task 'robot' must be true or false, got: the integer 1$"),
        ("E203", "rtpu: rtpu1", "rtpu: rtpu2", "rtpu2", r"task 'robot' runs on RTPU 'rtpu2', which 'rtpus' does not declare$"),
        ("E204", "q_d:   {type: float64, shape: [NDOF]", "q_d:   {type: float64, shape: [NDFO]", "NDFO",
         r"shape of variable 'q_d' uses dim 'NDFO', which 'dims' does not define$"),
        ("E303", "q_d:   {type: float64", "q_d:   {type: float46", "float46", r"variable 'q_d' has unknown type 'float46'$"),
        ("E501", "period: 2 ms", "period: 2 kg", "2 kg",
         r"period of task 'traj': expected a time like '1 ms' or a number of seconds, got: '2 kg'"),
        ("E501", "period: 2 ms", "period: 500 Hz", "500 Hz", r"period of task 'traj': .* \(that is a frequency\)$"),
        ("E502", "period: 2 ms", "period: -5 ms", "-5 ms", r"period of task 'traj' must be > 0, got: -5 ms$"),
        ("E503", "rate: 1 kHz", "rate: 1 kHz, period: 1 ms", "rate:", r"task 'pid' gives both a period and a rate$"),
        ("E504", ", period: 2 ms", "", "traj:", r"task 'traj' needs a period or a rate$"),
        ("E701", "object: q_d, post", "object: q_m, post", "q_m, post",
         r"job 'move' takes variable 'q_m' as its object, but the variable is not marked as an object$"),
        ("E210", "configuration: joint_pid", "configuration: joint_pd", "joint_pd,",
         r"job 'move' runs configuration 'joint_pd', which 'configurations' does not declare$"),
    ],
)
def test_each_rule_has_its_own_code(tmp_path: Path, code: str, old: str, new: str, needle: str, message: str) -> None:
    expect_error(tmp_path, changed(old, new), needle, message, code=code)


def test_every_diagnostic_of_the_legal_file_variants_carries_a_code(tmp_path: Path) -> None:
    text = changed("period: 2 ms", "period: 2 kg", changed("q_d:   {type: float64", "q_d:   {type: float46"))
    result = check(tmp_path, text)
    assert result.errors and all(re.match(r"^E\d{3}$", e.code) for e in result.errors)


# --- task names and modules ------------------------------------------------------------------


def test_two_tasks_with_one_name_are_a_duplicate_key_error_at_the_second(tmp_path: Path) -> None:
    text = changed("  pid:   {module", "  traj:  {module")
    error = only_error(check(tmp_path, text))
    line, column = at(text, "traj:", 1)
    assert re.match(rf"^.*bad\.yaml:{line}:{column}: error\[E102\]: "
                    r"duplicate key 'traj' in tasks \(first at line 14, column 3\)$", str(error), re.MULTILINE)


def test_one_module_may_run_as_different_tasks_in_different_configurations(tmp_path: Path) -> None:
    text = changed("configurations:\n", TRAJ2 + "configurations:\n")
    text = changed("  joint_pid:", "  other: [robot, traj2, pid]\n  joint_pid:", text)
    assert check(tmp_path, text).errors == []


# --- job conditions ------------------------------------------------------------------------


def test_a_condition_may_use_the_whole_language(tmp_path: Path) -> None:
    text = changed('post: "max(abs(q_m - q_d)) < 1e-3"',
                   'pre: "not any(abs(q_m) > 3.2) and norm(q_m[0:1] if 0 else q_m) >= 0", post: "max(abs(q_m - q_d)) < 1e-3"')
    error = only_error(check(tmp_path, text))  # the slice and the conditional expression are not in it
    assert error.code == "E703"
    text = changed('post: "max(abs(q_m - q_d)) < 1e-3"',
                   'pre: "not any(abs(q_m) > 3.2) and sqrt(sum(q_d ** 2)) >= 0 or min(q_m[0], -q_m[-1]) < 1", '
                   'post: "max(abs(q_m - q_d)) < 1e-3"')
    result = check(tmp_path, text)
    assert result.errors == [] and result.subsystem is not None
    assert result.subsystem.jobs["move"].pre is not None


def test_a_condition_in_block_style_is_reported_at_its_value(tmp_path: Path) -> None:
    text = changed('move: {configuration: joint_pid, object: q_d, post: "max(abs(q_m - q_d)) < 1e-3", timeout: 10 s}',
                   "move:\n    configuration: joint_pid\n    object: q_d\n    post: >-\n      lambda: 1\n    timeout: 10 s")
    error = only_error(check(tmp_path, text))
    assert error.code == "E703" and re.match(r"^post-condition of job 'move': a lambda is not allowed", error.message)
    assert error.line == at(text, ">-")[0]


# --- applications ---------------------------------------------------------------------------


def test_applications_may_nest_and_stay_complete(tmp_path: Path) -> None:
    text = with_apps(f"  demo:\n    - move: {{q_d: {Q}}}\n  outer:\n    - demo\n    - hold\n",
                     "  hold: {configuration: joint_pid, object: none}\n")
    result = check(tmp_path, text)
    assert result.errors == [] and result.warnings == []
    assert result.subsystem is not None
    outer = result.subsystem.applications["outer"]
    assert outer.complete and [(s.job, s.is_application) for s in outer.steps] == [("demo", True), ("hold", False)]


def test_an_application_using_an_incomplete_one_is_incomplete(tmp_path: Path) -> None:
    text = with_apps("  demo: [move]\n  outer: [demo]\n")
    result = check(tmp_path, text)
    warnings = expect_warnings(result, "W701", "W702")
    assert re.match(r"^application 'outer' is incomplete: step 1 'demo' is the incomplete application 'demo'$",
                    warnings[1].message)
    assert result.subsystem is not None
    assert not result.subsystem.applications["outer"].complete and not result.subsystem.applications["demo"].complete


def test_a_cycle_of_applications_is_an_error(tmp_path: Path) -> None:
    text = with_apps(f"  a: [b, {{move: {{q_d: {Q}}}}}]\n  b: [c]\n  c: [a]\n")
    error = only_error(check(tmp_path, text))
    assert error.code == "E708"
    assert re.match(r"^applications form a cycle: (a -> b -> c -> a|b -> c -> a -> b|c -> a -> b -> c)$", error.message)


# --- timing ---------------------------------------------------------------------------------


def test_a_task_may_declare_its_wcet(tmp_path: Path) -> None:
    result = check(tmp_path, changed("period: 2 ms}", "period: 2 ms, wcet: 0.2 ms}"))
    assert result.errors == [] and result.warnings == []
    assert result.subsystem is not None and result.subsystem.tasks["traj"].wcet == pytest.approx(2e-4)
    assert result.subsystem.tasks["pid"].wcet is None


def loads(traj: str, pid: str, traj_critical: bool = False, pid_critical: bool = False) -> str:
    text = changed("period: 2 ms}", f"period: 2 ms, wcet: {traj}, critical: {str(traj_critical).lower()}}}")
    return changed("params: {kp: 400}", f"wcet: {pid}, critical: {str(pid_critical).lower()}, params: {{kp: 400}}", text)


def test_an_rtpu_within_the_rate_monotonic_bound_has_no_warning(tmp_path: Path) -> None:
    assert check(tmp_path, loads("0.8 ms", "0.4 ms")).warnings == []  # U = 0.8 <= 0.828


def test_an_rtpu_beyond_the_rate_monotonic_bound_is_a_warning(tmp_path: Path) -> None:
    text = loads("1 ms", "0.4 ms")
    [warning] = expect_warnings(check(tmp_path, text), "W501")
    assert (warning.line, warning.column) == at(text, "joint_pid:")
    assert warning.message == (
        "RTPU 'rtpu0' in configuration 'joint_pid' exceeds the rate-monotonic bound: traj 0.500 (1 ms / 2 ms), "
        "pid 0.400 (0.4 ms / 1 ms); U = 0.900 > 0.828 = n(2^(1/n) - 1) for n = 2"
    )


def test_an_overloaded_rtpu_is_a_warning(tmp_path: Path) -> None:
    [warning] = expect_warnings(check(tmp_path, loads("1.5 ms", "0.5 ms")), "W502")
    assert re.match(r"^RTPU 'rtpu0' in configuration 'joint_pid' is overloaded: traj 0\.750 .*; U = 1\.250 > 1$", warning.message)


def test_critical_tasks_that_do_not_fit_alone_are_not_guaranteed_by_muf(tmp_path: Path) -> None:
    warnings = expect_warnings(check(tmp_path, loads("1 ms", "0.6 ms", True, True)), "W502", "W503")
    [muf] = [w for w in warnings if w.code == "W503"]
    assert re.match(r"^critical tasks of RTPU 'rtpu0' in configuration 'joint_pid' are not guaranteed: "
                    r"traj 0\.500 \(1 ms / 2 ms\), pid 0\.600 \(0\.6 ms / 1 ms\); U_critical = 1\.100 > 1$", muf.message)
    assert "Stewart & Khosla" in muf.hint


def test_an_overload_with_a_critical_set_that_fits_warns_only_of_the_overload(tmp_path: Path) -> None:
    expect_warnings(check(tmp_path, loads("1.5 ms", "0.5 ms", pid_critical=True)), "W502")


# --- aperiodic tasks --------------------------------------------------------------------------


def test_an_aperiodic_task_gives_its_min_interarrival(tmp_path: Path) -> None:
    result = check(tmp_path, changed("period: 2 ms}", "aperiodic: true, min_interarrival: 5 ms}"))
    assert result.errors == [] and result.subsystem is not None
    traj = result.subsystem.tasks["traj"]
    assert traj.aperiodic and traj.min_interarrival == pytest.approx(5e-3) and traj.period == pytest.approx(5e-3)
    assert not result.subsystem.tasks["pid"].aperiodic


# --- ten mistakes, one pass -----------------------------------------------------------------


def test_ten_mistakes_in_ten_sections_give_ten_located_messages_in_file_order(tmp_path: Path) -> None:
    mistakes = [
        ("subsystem: puma", "subsystem: my puma/1", "my puma", "E201"),
        ("rtpus: [rtpu0, rtpu1]", "rtpus: {rtpu0: {cpu: -1}, rtpu1: {cpu: 1}}", "-1", "E117"),
        ("exclusive: true", "exclusive: maybe", "maybe", "E115"),
        ("dims: {NDOF: 6}", "dims: {NDOF: 6, NX: six}", "six", "E116"),
        ("q_m:   {type: float64, shape: [NDOF]}", "q_m:   {type: float64, shape: [NDOF], unit: rad}", "unit", "E111"),
        ("period: 2 ms", "period: 2 kg", "2 kg", "E501"),
        ("ports: {tau: tau_u}", "ports: {tau: tau_u, torque: tau_u}", "torque", "E212"),
        ("[robot, traj, pid]", "[robot, traj, pid, gripper]", "gripper", "E209"),
        ('"max(abs(q_m - q_d)) < 1e-3"', '"q_m.max() < 1e-3"', "q_m.max", "E703"),
        ("- move: {q_d:", "- mvoe: {q_d:", "mvoe", "E211"),
    ]
    text = LEGAL
    for old, new, _, _ in mistakes:
        text = changed(old, new, text)
    result = check(tmp_path, text)
    expected = [(*at(text, needle), code) for _, _, needle, code in mistakes]
    assert [(e.line, e.column, e.code) for e in result.errors] == expected, format_all(result)
    assert len({e.line for e in result.errors}) == 10


def format_all(result: CheckResult) -> str:
    return "\n".join(e.format() for e in [*result.errors, *result.warnings])


# --- issue 22: an instance of a module is the module with the variables its outputs write ---------


def test_the_hint_of_e407_when_followed_gives_two_instances_of_one_module_issue_22(tmp_path: Path) -> None:
    text = edited(("configurations:\n", TRAJ2 + "configurations:\n"), ("[robot, traj, pid]", "[robot, traj, pid, traj2]"))
    hint = only_error(check(tmp_path, text)).hint
    declared, linked = re.search(r"declare '(\w+)' under variables:, link them with ports: (\{.*?\})\)", hint).groups()
    followed = edited(("  traj2: {module: fake_traj, rtpu: rtpu0, period: 2 ms}",
                       f"  traj2: {{module: fake_traj, rtpu: rtpu0, period: 2 ms, ports: {linked}}}"),
                      ("variables:\n", f"variables:\n  {declared}: {{type: float64, shape: [NDOF]}}\n"), text=text)
    assert check(tmp_path, followed).errors == []


def test_tasks_of_a_module_that_writes_nothing_may_run_side_by_side_issue_22(tmp_path: Path) -> None:
    text = edited(("variables:\n", "variables:\n  K: {type: float64, initial: 1}\n"),
                  ("tasks:\n", "tasks:\n  look1: {module: fake_k_reader, rtpu: rtpu0, period: 1 ms}\n"
                                "  look2: {module: fake_k_reader, rtpu: rtpu0, period: 5 ms}\n"),
                  ("[robot, traj, pid]", "[robot, traj, pid, look1, look2]"))
    assert check(tmp_path, text).errors == []


def test_a_second_pid_on_the_same_torque_is_still_one_module_twice_at_its_place_in_the_list_issue_22(tmp_path: Path) -> None:
    text = edited(("configurations:\n",
                   "  pid2: {module: fake_pid, rtpu: rtpu0, period: 1 ms, params: {kp: 1}, ports: {tau: tau_u}}\n"
                   "configurations:\n"), ("[robot, traj, pid]", "[robot, traj, pid, pid2]"))
    error = expect_error(tmp_path, text, "pid2]", r"configuration 'joint_pid' runs module 'fake_pid' twice: as task 'pid' "
                                                  r"\(line 15\) and as task 'pid2' \(line 16\), both writing tau_u$", code="E407")
    assert "ports: {tau: tau_u_pid2}" in error.hint
