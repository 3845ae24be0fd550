"""Object types, named objects, job classes, the job dictionary and gaps (Onika §4.3.3-4.4.2).

Each case changes one thing in a legal file of the shipped modules (the arm, a trajectory, two
controllers) and checks what `pbo check` says: the classes it infers, or one located error.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from pbo_runtime.cli import main
from pbo_runtime.config.loader import CheckResult, check_file, load_subsystem
from pbo_runtime.config.model import ACTION, ACTION_REQUIRING_OBJECT, INCOMPLETE, Gap, Subsystem
from pbo_runtime.edit.job_dictionary import edges, interlocks, job_dictionary, may_follow, row_gaps

READY = [0.3, -0.5, 0.5, 0.2, 0.4, 0.2]
LEGAL = f"""\
subsystem: dictionary_test
rtpus: [rtpu0, rtpu1]
plant: {{model: puma560, timestep: 1 ms}}
devices:
  arm: {{driver: mujoco_arm, mode: torque, exclusive: true}}
dims: {{NDOF: 6}}
variables:
  NDOF:  {{type: int32}}
  ARM:   {{type: float64, shape: [NDOF, 29]}}
  EE:    {{type: float64, shape: [8]}}
  q_m:   {{type: float64, shape: [NDOF]}}
  qd_m:  {{type: float64, shape: [NDOF]}}
  q_d:   {{type: float64, shape: [NDOF], object: joint_position, initial: 0}}
  q_r:   {{type: float64, shape: [NDOF]}}
  qd_r:  {{type: float64, shape: [NDOF]}}
  tau_u: {{type: float64, shape: [NDOF]}}
object_types:
  joint_position: {{type: float64, shape: [NDOF], unit: rad, doc: a position of the joints}}
objects:
  home:  {{type: joint_position, value: 0}}
  ready: {{type: joint_position, value: {READY}, doc: arm raised}}
tasks:
  robot: {{module: robot_torque, rtpu: rtpu1, period: 1 ms, critical: true, resources: [arm]}}
  traj:  {{module: joint_trajectory, rtpu: rtpu0, period: 2 ms, params: {{max_velocity: 1.0}}}}
  pid:   {{module: pid_joint, rtpu: rtpu0, period: 1 ms, params: {{kp: 400, kd: 40}}, ports: {{tau: tau_u}}}}
  pd:    {{module: pid_joint, rtpu: rtpu0, period: 1 ms, params: {{kp: 600, kd: 50}}, ports: {{tau: tau_u}}}}
configurations:
  pid: [robot, traj, pid]
  pd:  [robot, traj, pd]
jobs:
  reach:  {{configuration: pid, post: "max(abs(q_m - q_d)) < 0.01", timeout: 10 s}}
  settle: {{configuration: pd, object: q_d}}
  hold:   {{configuration: pd, object: none}}
applications:
  tour:
    - reach: home
    - settle: {{q_d: ready}}
    - hold
"""


def check(tmp_path: Path, text: str, name: str = "subsystem.yaml") -> CheckResult:
    path = tmp_path / name
    path.write_text(text)
    return check_file(path)


def changed(old: str, new: str, text: str = LEGAL) -> str:
    assert old in text, old
    return text.replace(old, new, 1)


def with_applications(extra: str, text: str = LEGAL) -> str:
    return text + extra


def only_error(result: CheckResult):
    assert len(result.errors) == 1, "\n".join(e.format() for e in result.errors)
    return result.errors[0]


def line_of(text: str, needle: str) -> tuple[int, int]:
    """(line, column), 1-based, of the first line holding `needle`; "context>>part": of `part` after `context`."""
    context, _, part = needle.partition(">>")
    line_number, line = next((i, line) for i, line in enumerate(text.splitlines(), 1) if context in line)
    start = line.index(context)
    return line_number, (line.index(part, start) if part else start) + 1


@pytest.fixture
def subsystem(tmp_path) -> Subsystem:
    path = tmp_path / "legal.yaml"
    path.write_text(LEGAL + "  approach: [reach, settle]\n  visit:\n    - approach: ready\n"
                            f"    - approach: {{joint_position: {[0.1] * 6}}}\n")
    return load_subsystem(path)


# --- the legal file -----------------------------------------------------------------------------


def test_a_legal_file_checks_clean_with_its_object_types_objects_and_job_classes(tmp_path):
    result = check(tmp_path, LEGAL)
    assert result.errors == [] and result.warnings == [], [e.format() for e in result.errors + result.warnings]
    sub = result.subsystem
    assert sub is not None
    kind = sub.object_types["joint_position"]
    assert (kind.dtype, kind.shape, kind.unit, kind.declared) == ("float64", (6,), "rad", True)
    assert sub.objects["home"].value.tolist() == [0.0] * 6 and sub.objects["ready"].value.tolist() == READY
    assert not sub.objects["ready"].value.flags.writeable
    assert [(j.name, j.kind, j.object, j.object_type) for j in sub.jobs.values()] == [
        ("reach", ACTION_REQUIRING_OBJECT, "q_d", "joint_position"),  # inferred: traj reads q_d, no task writes it
        ("settle", ACTION_REQUIRING_OBJECT, "q_d", "joint_position"),  # written, and it agrees
        ("hold", ACTION, None, None),  # object: none: the trajectory keeps the goal it has
    ]
    tour = sub.applications["tour"]
    assert tour.complete and tour.gaps == () and tour.kind == ACTION
    assert [(s.job, s.object, dict(s.arguments)) for s in tour.steps] == [
        ("reach", "home", {}), ("settle", "ready", {}), ("hold", None, {})]


def test_without_object_types_each_type_is_implied_by_the_variables_marked_with_it(tmp_path):
    text = changed("object_types:\n  joint_position: {type: float64, shape: [NDOF], unit: rad, doc: a position of the joints}\n",
                   "")
    result = check(tmp_path, text)
    assert result.errors == [] and result.subsystem is not None
    kind = result.subsystem.object_types["joint_position"]
    assert (kind.dtype, kind.shape, kind.declared) == ("float64", (6,), False)
    assert result.subsystem.jobs["reach"].object_type == "joint_position"


def test_object_types_and_objects_may_come_from_an_included_file_and_a_name_given_twice_is_located(tmp_path):
    library = ("object_types:\n  joint_position: {type: float64, shape: [6], unit: rad}\n"
               "objects:\n  home: {type: joint_position, value: 0}\n")
    (tmp_path / "poses.yaml").write_text(library)
    text = changed("object_types:\n  joint_position: {type: float64, shape: [NDOF], unit: rad, doc: a position of the joints}\n",
                   "")
    text = changed("objects:\n  home:  {type: joint_position, value: 0}\n", "objects:\n", text)
    result = check(tmp_path, "include: [poses.yaml]\n" + text)
    assert result.errors == [] and result.subsystem is not None
    assert result.subsystem.objects["home"].loc.file.endswith("poses.yaml")
    without_types = LEGAL.replace("object_types:\n  joint_position: {type: float64, shape: [NDOF], unit: rad, "
                                  "doc: a position of the joints}\n", "")
    twice = check(tmp_path, "include: [poses.yaml]\n" + changed("objects:\n  home:  {type: joint_position, value: 0}\n",
                                                                "objects:\n  home:  {type: joint_position, value: 1}\n",
                                                                text=without_types), name="twice.yaml")
    error = only_error(twice)
    assert error.code == "E215" and re.match(r"^'home' in 'objects' is defined twice: here and at .*poses\.yaml:4:3$",
                                             error.message)


# --- one mistake, one located error ----------------------------------------------------------------

# a configuration whose controller reads the references directly: they have initial values, no writer
STILL = changed("configurations:\n", "configurations:\n  still: [robot, pid]\n", changed(
    "  q_r:   {type: float64, shape: [NDOF]}", "  q_r:   {type: float64, shape: [NDOF], initial: 0}", changed(
        "  qd_r:  {type: float64, shape: [NDOF]}", "  qd_r:  {type: float64, shape: [NDOF], initial: 0}")))

MISTAKES = [
    pytest.param(changed("  home:  {type: joint_position,", "  home:  {type: joint_positon,"), "joint_positon",
                 r"^object 'home' has type 'joint_positon', which no object type declares$", "E711",
                 r"did you mean 'joint_position'",
                 id="an_objects_type_must_be_declared"),
    pytest.param(changed("object: joint_position, initial: 0", "object: joint_pos, initial: 0"), "joint_pos",
                 r"^variable 'q_d' is marked object: 'joint_pos', which 'object_types' does not declare$", "E711", "did you mean",
                 id="once_object_types_is_given_a_marking_must_name_one"),
    pytest.param(changed("joint_position: {type: float64, shape: [NDOF]", "joint_position: {type: float64, shape: [3]",
                         changed(f"value: {READY}", "value: [1, 2, 3]")), "object: joint_position, initial>>joint_position",
                 r"^variable 'q_d' \(float64 \(6,\)\) is marked object: 'joint_position', "
                 r"but objects of type 'joint_position' are float64 \(3,\)$",
                 "E712", None, id="a_marked_variable_has_its_types_dtype_and_shape"),
    pytest.param(changed("joint_position: {type: float64,", "joint_position: {type: float46,"), "float46",
                 r"^object type 'joint_position' has unknown type 'float46'$", "E303", "did you mean 'float64'",
                 id="an_object_types_dtype_is_a_table_dtype"),
    pytest.param(changed("shape: [NDOF], unit", "shape: [NDFO], unit"), "NDFO",
                 r"^shape of object type 'joint_position' uses dim 'NDFO', which 'dims' does not define$", "E204", None,
                 id="an_object_types_shape_uses_defined_dims"),
    pytest.param(changed("value: [0.3, -0.5,", "value: [0.3, -0.5, 0.1,"), "[0.3, -0.5, 0.1",
                 r"^value of object 'ready' has shape \(7,\), but the shape of object type 'joint_position' is \(6,\)$", "E312",
                 None,
                 id="an_objects_value_has_its_types_shape"),
    pytest.param(changed("value: [0.3, -0.5,", "value: [.nan, -0.5,"), ".nan",
                 r"^value of object 'ready': float64 elements must be finite numbers, got: \.nan", "E314", None,
                 id="an_objects_value_is_finite"),
    pytest.param(changed("  home:  {type: joint_position, value: 0}", "  home:  {type: joint_position}"), "home:",
                 r"^object 'home' has no 'value:', which is required$", "E112", None, id="an_object_has_a_value"),
    pytest.param(changed("    - reach: home", "    - reach: hmoe"), "hmoe",
                 r"^step 1 of application 'tour' gives object 'hmoe' to job 'reach', but 'objects' declares no such object$",
                 "E714",
                 "did you mean 'home'", id="a_step_names_a_declared_object"),
    pytest.param(changed("    - hold\n", "    - hold: home\n"), "- hold: home>>home",
                 r"^step 3 of application 'tour' gives object 'home' to job 'hold', which takes no object$", "E705", None,
                 id="an_action_takes_no_named_object"),
    pytest.param(changed("  settle: {configuration: pd, object: q_d}", "  settle: {configuration: pd, object: qd_m}"), "qd_m}",
                 r"^job 'settle' takes variable 'qd_m' as its object, but the variable is not marked as an object$", "E701", None,
                 id="a_written_object_is_a_marked_variable"),
    pytest.param(changed("jobs:\n", "jobs:\n  fixed: {configuration: still, object: q_d}\n", STILL),
                 "fixed: {configuration: still, object: q_d}>>q_d}",
                 r"^job 'fixed' takes object 'q_d', but no task of configuration 'still' reads or writes it$", "E715",
                 r"^its tasks need no object: remove object:, and the job is an action$", id="a_written_object_some_task_uses"),
    pytest.param(changed("jobs:\n", "jobs:\n  servo: {configuration: still}\n", STILL.replace(
                     "initial: 0}", "object: joint_position, initial: 0}")
                         .replace("object: joint_position, object: joint_position", "object: joint_position")),
                 "servo:",
                 r"^job 'servo' needs more than one object: configuration 'still' reads "
                 r"'q_r' \(type joint_position, read by 'pid'\), 'qd_r' \(type joint_position, read by 'pid'\), "
                 r"but a job takes one$", "E716", "object: <variable>",
                 id="a_job_reading_two_objects_chooses_one"),
    pytest.param(changed("objects:\n", "objects:\n  reach: {type: joint_position, value: 1}\n"), "reach: {type",
                 r"^'reach' names both an object and a job$", "E717", None, id="an_object_and_a_job_have_different_names"),
]


@pytest.mark.parametrize(("text", "needle", "message", "code", "hint"), MISTAKES)
def test_one_mistake_is_one_located_error(tmp_path, text, needle, message, code, hint):
    error = only_error(check(tmp_path, text))
    assert (error.code, re.search(message, error.message) is not None) == (code, True), error.format()
    assert (error.line, error.column) == line_of(text, needle), error.format()
    if hint:
        assert re.search(hint, error.hint), error.hint


def test_a_named_object_of_another_type_does_not_interlock(tmp_path):
    text = changed("objects:\n", "  gain: {type: float64}\nobjects:\n  k: {type: gain, value: 2}\n")
    text = changed("    - reach: home", "    - reach: k", text)
    error = only_error(check(tmp_path, text))
    assert error.code == "E713" and error.message == (
        "step 1 of application 'tour' gives object 'k' of type gain to job 'reach', which needs an object of type joint_position")
    assert error.hint == "objects of type joint_position: home, ready" and error.line == line_of(text, "reach: k")[0]


def test_two_variables_implying_one_type_differently_is_an_error_at_the_second(tmp_path):
    text = changed("object_types:\n  joint_position: {type: float64, shape: [NDOF], unit: rad, doc: a position of the joints}\n",
                   "")
    text = changed("  q_r:   {type: float64, shape: [NDOF]}",
                   "  q_r:   {type: float64, shape: [NDOF]}\n  g:     {type: float64, object: joint_position}", text)
    result = check(tmp_path, text)
    e712 = [e for e in result.errors if e.code == "E712"]
    assert len(e712) == 1 and e712[0].message == (
        "variables 'q_d' (float64 (6,)) and 'g' (float64 () (a scalar)) are both marked object: 'joint_position'")


# --- incomplete applications as actions requiring an object ----------------------------------------


def test_an_incomplete_application_of_one_object_type_is_an_action_requiring_an_object(subsystem):
    approach = subsystem.applications["approach"]
    assert not approach.complete and approach.kind == ACTION_REQUIRING_OBJECT and approach.object_type == "joint_position"
    assert approach.gaps == (Gap(1, "reach", "joint_position"), Gap(2, "settle", "joint_position"))
    visit = subsystem.applications["visit"]
    assert visit.complete and visit.kind == ACTION
    first, second = visit.steps
    assert (first.job, first.is_application, first.object, first.fill) == ("approach", True, "ready", None)
    assert (second.object, second.fill) == (None, [0.1] * 6)


def test_an_incomplete_application_used_unfilled_leaves_its_user_incomplete_with_one_gap_of_its_type(tmp_path):
    text = with_applications("  approach: [reach, settle]\n  outer: [hold, approach]\n  top: [{outer: home}]\n")
    result = check(tmp_path, text)
    assert result.errors == []
    assert [w.code for w in result.warnings] == ["W701", "W701", "W702"]
    assert "give it an object of type joint_position ('- approach: <object>')" in result.warnings[2].hint
    sub = result.subsystem
    assert sub is not None
    assert sub.applications["outer"].gaps == (Gap(2, "approach", "joint_position"),)
    assert sub.applications["outer"].kind == ACTION_REQUIRING_OBJECT and sub.applications["top"].complete


@pytest.mark.parametrize(("extra", "needle", "message", "code"), [
    ("  whole: [hold]\n  outer: [{whole: home}]\n", "home}]",
     r"^step 1 of application 'outer' gives objects to application 'whole', which takes none$", "E709"),
    ("  approach: [reach]\n  outer: [{approach: {q_d: 0}}]\n", "q_d: 0",
     r"^step 1 of application 'outer' gives q_d to application 'approach', whose gaps take one object of type joint_position$",
     "E707"),
    ("  approach: [reach]\n  outer: [{approach: {joint_position: [1, 2]}}]\n", "[1, 2]",
     r"^object of step 1 of application 'outer' has shape \(2,\), but the shape of object type 'joint_position' is \(6,\)$",
     "E312"),
    ("  approach: [reach]\n  outer: [{approach: nowhere}]\n", "nowhere",
     r"^step 1 of application 'outer' gives object 'nowhere' to application 'approach', but 'objects' declares no such object$",
     "E714"),
])
def test_what_an_application_is_given_must_fill_its_gaps(tmp_path, extra, needle, message, code):
    text = with_applications(extra)
    error = only_error(check(tmp_path, text))
    assert error.code == code and re.search(message, error.message), error.format()
    assert (error.line, error.column) == line_of(text, needle), error.format()


def test_one_object_for_gaps_of_several_types_is_refused(tmp_path):
    text = changed("  q_r:   {type: float64, shape: [NDOF]}",
                   "  q_r:   {type: float64, shape: [NDOF], object: joint_reference, initial: 0}")
    text = changed("  qd_r:  {type: float64, shape: [NDOF]}", "  qd_r:  {type: float64, shape: [NDOF], initial: 0}", text)
    text = changed("  joint_position: {type", "  joint_reference: {type: float64, shape: [NDOF]}\n  joint_position: {type", text)
    text = changed("configurations:\n", "configurations:\n  still: [robot, pid]\n", text)
    text = changed("jobs:\n", "jobs:\n  servo: {configuration: still}\n", text)
    text = with_applications("  both: [reach, servo]\n  outer: [{both: home}]\n", text)
    result = check(tmp_path, text)
    error = only_error(result)
    assert error.code == "E718" and error.message == (
        "step 1 of application 'outer' gives an object to application 'both', whose gaps need objects of types "
        "joint_position, joint_reference: no one object fills them "
        "(step 1 'reach' (joint_position), step 2 'servo' (joint_reference))")
    # kept, not refused: the mixed application itself is incomplete, with a gap of each type
    clean = check(tmp_path, text.replace("  outer: [{both: home}]\n", "  outer: [both]\n"), name="clean.yaml")
    assert clean.errors == [] and clean.subsystem is not None
    assert clean.subsystem.applications["both"].kind == INCOMPLETE
    assert clean.subsystem.applications["outer"].gaps == (Gap(1, "both", None),)


# --- the dictionary, edges and gaps ------------------------------------------------------------------


def test_the_job_dictionary_gives_each_icon_its_class_type_and_edges_as_plain_data(subsystem):
    dictionary = job_dictionary(subsystem)
    assert json.loads(json.dumps(dictionary)) == dictionary  # plain data: the API hands it on as it is
    assert dictionary["object_types"]["joint_position"] == {
        "index": 0, "type": "float64", "shape": [6], "unit": "rad", "doc": "a position of the joints", "declared": True,
        "variables": ["q_d"], "range": None, "objects": ["home", "ready"]}
    notch = {"left": {"shape": "flat", "object_type": None}, "right": {"shape": "notch", "object_type": "joint_position"}}
    flat = {"left": {"shape": "flat", "object_type": None}, "right": {"shape": "flat", "object_type": None}}
    tab = {"left": {"shape": "tab", "object_type": "joint_position"}, "right": {"shape": "flat", "object_type": None}}
    assert {n: (j["class"], j["object_type"], j["edges"]) for n, j in dictionary["jobs"].items()} == {
        "reach": (ACTION_REQUIRING_OBJECT, "joint_position", notch), "settle": (ACTION_REQUIRING_OBJECT, "joint_position", notch),
        "hold": (ACTION, None, flat)}
    assert dictionary["objects"]["ready"] == {"class": "object", "type": "joint_position", "value": READY, "doc": "arm raised",
                                              "edges": tab}
    approach = dictionary["applications"]["approach"]
    assert (approach["class"], approach["complete"], approach["edges"]) == (ACTION_REQUIRING_OBJECT, False, notch)
    assert approach["gaps"] == [{"step": 1, "job": "reach", "object_type": "joint_position"},
                                {"step": 2, "job": "settle", "object_type": "joint_position"}]
    assert dictionary["applications"]["visit"]["steps"] == [
        {"step": 1, "job": "approach", "application": True, "object": "ready", "value": None},
        {"step": 2, "job": "approach", "application": True, "object": None, "value": [0.1] * 6}]


@pytest.mark.parametrize(("left", "right", "fits"), [
    ("hold", "reach", True),  # flat against flat
    ("reach", "home", True),  # notch against the tab of its type
    ("approach", "ready", True),  # an incomplete application of one type takes an object like a job
    ("reach", "hold", False),  # a notch against a flat edge: a gap goes between them
    ("hold", "home", False),  # an object needs a notch on its left
    ("home", "reach", True),  # an object's right edge is flat
    ("home", "ready", False),
    ("reach", "nothing", False),
])
def test_icons_sit_side_by_side_only_when_their_edges_interlock(subsystem, left, right, fits):
    assert may_follow(subsystem, left, right) is fits


def test_a_notch_takes_only_the_tab_of_its_own_type():
    assert interlocks(edges(ACTION_REQUIRING_OBJECT, "a"), edges("object", "a"))
    assert not interlocks(edges(ACTION_REQUIRING_OBJECT, "a"), edges("object", "b"))
    assert interlocks(edges(INCOMPLETE), edges(ACTION))


def test_a_partial_application_tells_where_each_gap_is_and_of_which_type(subsystem):
    answer = row_gaps(subsystem, ["reach", "home", "settle", "hold", "approach", {"reach": "ready"}])
    assert answer["gaps"] == [
        {"item": 2, "step": 2, "job": "settle", "object_type": "joint_position", "insert_at": 3},
        {"item": 4, "step": 4, "job": "approach", "object_type": "joint_position", "insert_at": 5}]
    assert [(s["name"], s["object"]) for s in answer["steps"]] == [
        ("reach", "home"), ("settle", None), ("hold", None), ("approach", None), ("reach", "ready")]
    assert answer["problems"] == [] and answer["complete"] is False
    assert row_gaps(subsystem, ["reach", "home", "approach", "ready"])["complete"] is True


@pytest.mark.parametrize(("row", "message"), [
    (["hold", "home"], "object 'home' (type joint_position) does not interlock with 'hold', which takes no object there"),
    (["home"], "object 'home' (type joint_position) does not interlock with the start of the application"),
    (["reach", "home", "ready"],
     "object 'ready' (type joint_position) does not interlock with 'home', which takes no object there"),
    (["fly"], "'fly' is no job, application or object of this subsystem"),
    ([{"hold": "home"}], "'hold' takes no object"),
    ([{"reach": "nowhere"}], "'reach' is given object 'nowhere', which is no object of this subsystem"),
    ([42], "item 0 is no icon name: 42"),
])
def test_a_partial_application_names_the_icons_that_do_not_interlock(subsystem, row, message):
    answer = row_gaps(subsystem, row)
    assert [p["message"] for p in answer["problems"]] == [message] and answer["complete"] is False


# --- pbo check ---------------------------------------------------------------------------------------


def test_check_json_has_the_job_dictionary_and_each_applications_steps_gaps_and_transitions(tmp_path, capsys):
    path = tmp_path / "incomplete.yaml"
    path.write_text(LEGAL + "  approach: [reach, settle]\n")
    assert main(["check", str(path), "--format", "json"]) == 0
    verdict = json.loads(capsys.readouterr().out)
    assert set(verdict) >= {"object_types", "objects", "jobs", "applications"}
    assert verdict["objects"]["home"]["value"] == [0.0] * 6 and verdict["objects"]["home"]["type"] == "joint_position"
    assert verdict["jobs"]["hold"]["class"] == ACTION and verdict["jobs"]["reach"]["edges"]["right"]["shape"] == "notch"
    approach = verdict["applications"]["approach"]
    assert approach["complete"] is False and [g["step"] for g in approach["gaps"]] == [1, 2]
    assert [t["to"] for t in approach["transitions"]] == ["pid", "pd"]
    assert [w["code"] for w in verdict["warnings"]] == ["W701", "W701"]


def test_check_prints_a_short_job_dictionary(tmp_path, capsys):
    path = tmp_path / "legal.yaml"
    path.write_text(LEGAL)
    assert main(["check", str(path)]) == 0
    out = capsys.readouterr().out
    assert ("  job dictionary:\n    actions: hold, tour\n    actions requiring an object: reach, settle (joint_position)\n"
            "    objects: home, ready (joint_position)\n") in out


def test_an_objects_value_is_the_array_job_control_writes(subsystem):
    assert np.array_equal(subsystem.objects["ready"].value, np.array(READY))
    assert subsystem.objects["ready"].value.dtype == np.float64


def test_the_examples_of_the_configuration_guide_check_and_print_the_dictionary_it_shows(tmp_path, capsys):
    guide = (Path(__file__).resolve().parent.parent / "docs" / "configuration.md").read_text()

    def block(section: str, fence: str = "```yaml\n") -> str:
        return guide.split(f"\n## {section}\n", 1)[1].split(fence, 1)[1].split("```", 1)[0]

    head = LEGAL.split("object_types:\n", 1)[0]
    tasks = LEGAL.split("tasks:\n", 1)[1].split("  pd:", 1)[0]
    text = (head + block("object_types, objects") + "tasks:\n" + tasks + "configurations:\n  joint_pid: [robot, traj, pid]\n"
            + block("jobs") + block("applications"))
    path = tmp_path / "guide.yaml"
    path.write_text(text)
    assert main(["check", str(path)]) == 0
    out = capsys.readouterr().out
    assert [line.split("]")[0] for line in out.splitlines() if "warning[" in line] == [
        f"{path}:{line_of(text, 'approach: [reach')[0]}:{c}: warning[W701" for c in (14, 21)]
    shown = guide.split("### The job dictionary\n", 1)[1].split("```\n", 1)[1].split("```", 1)[0]
    assert shown in out
