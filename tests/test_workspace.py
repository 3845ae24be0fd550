"""The user level's logic without a browser: the workspace's row as file steps and run steps, saving
an application or an object's value into the file (checked, comments kept), and `pbo app NAME --steps`
on a live subsystem (a fake job host: no process, a manual clock).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from pbo_runtime.config.loader import check_file, format_diagnostics, load_subsystem
from pbo_runtime.edit.live_save import saved_text
from pbo_runtime.edit.workspace import RowRefused, Step, check_name, checked_row, file_steps, parse_row, run_steps
from pbo_runtime.edit.workspace_file import SaveRefused, save_application, save_object
from pbo_runtime.ipc.control import BadRequest
from pbo_runtime.supervisor.commands import dispatch
from tests.fake_job_host import FakeJobHost, fake_subsystem

READY = [0.3, -0.5, 0.5, 0.2, 0.4, 0.2]


@pytest.fixture
def subsystem(tmp_path):
    return fake_subsystem(tmp_path)


def row(*items: str | tuple[str, str]) -> list[dict]:
    return [{"name": item, "object": None} if isinstance(item, str) else {"name": item[0], "object": item[1]} for item in items]


# --- the row ------------------------------------------------------------------------------------


def test_a_row_becomes_the_steps_a_file_writes_with_a_gap_left_as_the_jobs_name(subsystem):
    steps = checked_row(subsystem, row(("reach", "ready"), "hold", "settle"), run=False)
    assert file_steps(steps) == [{"reach": "ready"}, "hold", "settle"]


def test_a_row_to_run_gives_each_named_object_as_its_value_now(subsystem):
    steps = checked_row(subsystem, row(("reach", "ready"), "hold"), run=True)
    assert run_steps(subsystem, steps) == [{"reach": {"q_d": READY}}, "hold"]


@pytest.mark.parametrize("items, refusal", [
    (["reach", "settle"], r"^the application has 2 gaps and cannot run: step 1 'reach' needs an object of type "
                          r"joint_position; step 2 'settle' needs an object of type joint_position; drop an object"),
    ([("hold", "ready")], r"^the icons do not interlock: step 1: 'hold' takes no object$"),
    (["nope"], r"^the icons do not interlock: step 1: 'nope' is no job, application or object of this subsystem$"),
])
def test_a_row_with_a_gap_or_icons_that_do_not_interlock_is_refused_a_run_saying_why(subsystem, items, refusal):
    with pytest.raises(RowRefused, match=refusal):
        checked_row(subsystem, row(*items), run=True)


@pytest.mark.parametrize("given, refusal", [([], r"^the workspace is empty"), ([{"name": 3}], r"^step 1 of the row is not"),
                                            ("reach", r"^the workspace is empty"),
                                            ([{"name": "reach", "object": 7}], r"^step 1 of the row is not")])
def test_a_row_that_is_not_a_list_of_steps_is_refused(given, refusal):
    with pytest.raises(RowRefused, match=refusal):
        parse_row(given)


@pytest.mark.parametrize("name", ["", "2fast", "has space", "x" * 41, None])
def test_an_application_name_must_be_an_identifier(name):
    with pytest.raises(RowRefused, match=r"^an application's name is a letter"):
        check_name(name)


# --- saving into the file ---------------------------------------------------------------------------


def test_an_incomplete_application_is_saved_with_comments_kept_and_becomes_an_action_requiring_an_object(subsystem):
    file = subsystem.file
    before = Path(file).read_text()
    result = save_application(file, "approach", file_steps([Step("reach"), Step("hold")]))
    text = Path(file).read_text()
    assert result.ok and [w.code for w in result.warnings] == ["W701"], format_diagnostics(result)
    assert text.startswith(before.rstrip("\n").rsplit("\napplications:", 1)[0])  # every line above as it was
    assert "# Both jobs need an object (a joint_position)" in text
    assert "  approach:\n    - reach\n    - hold\n" in text
    approach = result.subsystem.applications["approach"]
    assert approach.kind == "action_requiring_object" and approach.object_type == "joint_position"


def test_an_application_is_saved_under_applications_when_the_file_has_none(tmp_path):
    subsystem = fake_subsystem(tmp_path)
    text = Path(subsystem.file).read_text()
    start = text.index("\napplications:")
    Path(subsystem.file).write_text(text[:start + 1])
    result = save_application(subsystem.file, "demo", [{"reach": "ready"}, "hold"])
    assert result.ok and list(result.subsystem.applications) == ["demo"]
    assert Path(subsystem.file).read_text().endswith("applications:\n  demo:\n    - reach: ready\n    - hold\n")


def test_saving_over_an_application_needs_replace_and_a_refused_save_leaves_the_file_as_it_was(subsystem):
    file = subsystem.file
    before = Path(file).read_text()
    with pytest.raises(SaveRefused, match=r"^application 'tour' exists in .*: choose another name, or replace it$"):
        save_application(file, "tour", ["hold"])
    with pytest.raises(SaveRefused, match=r"^not saved: .* would have 1 error, the first: .*error\[E717\]"):
        save_application(file, "ready", ["hold"])  # named like an object
    assert Path(file).read_text() == before
    assert save_application(file, "tour", ["hold"], replace=True).ok
    assert load_subsystem(file).applications["tour"].steps[0].job == "hold"


def test_an_objects_value_is_saved_in_its_entry_and_checked_against_its_type_first(subsystem):
    file = subsystem.file
    result = save_object(file, subsystem, "ready", [0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    assert result.ok
    assert "  ready: {type: joint_position, value: [0.1, 0.2, 0.3, 0.4, 0.5, 0.6], doc: \"upper arm raised, elbow bent\"}\n" \
        in Path(file).read_text()
    assert result.subsystem.objects["ready"].value.tolist() == [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]


@pytest.mark.parametrize("name, value, refusal", [
    ("ready", [1, 2, 3], r"object 'ready' \(type joint_position\)"),
    ("ready", [0, 0, 0, 0, 0, float("nan")], r"object 'ready' \(type joint_position\)"),
    ("ready", "fast", r"object 'ready' \(type joint_position\)"),
    ("nope", 0, r"^no object 'nope' in .* \(objects: ready\)$"),
])
def test_an_objects_value_that_does_not_fit_its_type_is_refused_and_the_file_kept(subsystem, name, value, refusal):
    before = Path(subsystem.file).read_text()
    with pytest.raises(SaveRefused, match=refusal):
        save_object(subsystem.file, subsystem, name, value)
    assert Path(subsystem.file).read_text() == before


def test_an_objects_value_outside_its_types_range_is_refused_as_pbo_check_refuses_it(subsystem):
    text = Path(subsystem.file).read_text()
    declared = re.search(r"^  joint_position: \{.*\}$", text, re.MULTILINE)
    assert declared is not None
    ranged = text.replace(declared[0], declared[0][:-1] + ", range: [-1, 1]}")
    Path(subsystem.file).write_text(ranged)
    with pytest.raises(SaveRefused,
                       match=r"^object 'ready' \(type joint_position\): element 3 must be in \[-1, 1\] \(the range of "
                             r"object type 'joint_position'\), got: 1\.5$"):
        save_object(subsystem.file, load_subsystem(subsystem.file), "ready", [0, 0, 1.5, 0, 0, 0])
    assert Path(subsystem.file).read_text() == ranged


# --- running a row on the live subsystem --------------------------------------------------------------


def test_an_application_given_with_its_steps_is_checked_adopted_and_started(subsystem):
    host = FakeJobHost(subsystem, "pid")
    reply = dispatch(host, "app", {"application": "workspace", "steps": [{"reach": {"q_d": READY}}, "hold"]})
    assert host.started_applications == ["workspace"] and reply["jobs"] == ["reach", "hold"]
    assert host.subsystem.applications["workspace"].complete
    saved = saved_text(host.live)  # pbo save writes it too, under applications:
    assert "  workspace:\n    - reach: {q_d: [0.3, -0.5, 0.5, 0.2, 0.4, 0.2]}\n    - hold\n" in saved


@pytest.mark.parametrize("steps, refusal", [
    (["reach"], r"application 'workspace' is incomplete"),
    (["hold", {"reach": "hold"}], r"E713|E714"),
    ([], r"its steps are a non-empty list"),
    ("[hold", r"not a YAML value"),
])
def test_an_application_given_with_steps_that_do_not_check_is_refused_before_anything_runs(subsystem, steps, refusal):
    host = FakeJobHost(subsystem, "pid")
    with pytest.raises(BadRequest, match=refusal):
        dispatch(host, "app", {"application": "workspace", "steps": steps})
    assert host.started_applications == []


def test_the_steps_may_be_given_as_yaml_text_as_the_command_line_sends_them(subsystem):
    host = FakeJobHost(subsystem, "pid")
    dispatch(host, "app", {"application": "again", "steps": "[reach: ready, hold]"})
    assert host.started_applications == ["again"]
    assert check_file(subsystem.file).ok  # the file itself is not written: pbo save does that


# --- steps that decide in the row ---------------------------------------------------------------------


def deciding_row(fallback_object: str | None) -> list[dict]:
    return [{"kind": "try", "rows": [row("guarded"), row(("reach", fallback_object) if fallback_object else "reach")]},
            {"kind": "repeat", "times": 2, "rows": [row("dwell")]},
            {"kind": "wait", "condition": "q_m[0] > -1", "timeout": "1 s", "rows": []},
            {"kind": "if", "condition": "q_m[0] > 0.1", "rows": [row("hold"), []]}]


def test_steps_that_decide_in_a_row_become_the_steps_a_file_writes_and_run_with_values(subsystem):
    steps = checked_row(subsystem, deciding_row("ready"), run=True)
    assert file_steps(steps) == [{"try": ["guarded"], "fallback": [{"reach": "ready"}]}, {"repeat": ["dwell"], "times": 2},
                                 {"wait": "q_m[0] > -1", "timeout": "1 s"}, {"if": "q_m[0] > 0.1", "then": ["hold"]}]
    assert run_steps(subsystem, steps)[0] == {"try": ["guarded"], "fallback": [{"reach": {"q_d": READY}}]}


def test_a_gap_inside_a_step_that_decides_is_named_by_where_it_is_and_refuses_a_run(subsystem):
    with pytest.raises(RowRefused, match=re.escape("the application has 1 gap and cannot run: step 1 (try, fallback): step 1 "
                                                   "'reach' needs an object of type joint_position")):
        checked_row(subsystem, deciding_row(None), run=True)


def test_a_step_that_decides_with_the_wrong_rows_is_refused(subsystem):
    with pytest.raises(RowRefused, match=r"^step 1 \(try\) must have 2 row\(s\) of steps \(try, fallback\)"):
        parse_row([{"kind": "try", "rows": [row("hold")]}])


def test_a_row_with_steps_that_decide_runs_on_a_live_subsystem(subsystem):
    host = FakeJobHost(subsystem, "pd")
    steps = run_steps(subsystem, checked_row(subsystem, deciding_row("ready"), run=True))
    reply = dispatch(host, "app", {"application": "workspace", "steps": steps})
    assert host.started_applications == ["workspace"] and reply["jobs"] == []
    assert reply["message"] == "application 'workspace' runs its steps, deciding as it goes; pbo status shows where it is"
    assert [step.decision.kind for step in host.subsystem.applications["workspace"].steps if step.decision] == [
        "try", "repeat", "wait", "if"]
