"""The checker's rules for steps that decide: every path interlocks, conditions fit their variables, repeats end."""

from __future__ import annotations

import re

import pytest

from pbo_runtime.cli.main import main
from pbo_runtime.config.decisions import paths
from pbo_runtime.config.loader import check_file, load_subsystem
from tests.support import REPO

BRANCHES = REPO / "configs" / "branches.yaml"
BASE = BRANCHES.read_text().split("\napplications:\n")[0].replace(
    "\njobs:\n", "\njobs:\n  drift:    {configuration: pid}                        # no condition: it cannot fail\n")


def checked(tmp_path, applications: str):
    path = tmp_path / "bad.yaml"
    path.write_text(BASE + "\napplications:\n" + applications)
    return check_file(str(path)), path


def line_of(path, text: str) -> int:
    return next(n for n, line in enumerate(path.read_text().splitlines(), 1) if text in line)


def test_the_shipped_example_checks_without_a_warning():
    result = check_file(str(BRANCHES))
    assert result.errors == [] and result.warnings == []
    assert result.subsystem is not None and result.subsystem.applications["pick"].complete


@pytest.mark.parametrize("code, steps, message, marker", [
    ("E720", '    - if: "q_m[0] > 0"\n      than: [reach: ready]\n',
     r"the if of step 1 of application 'a': unknown key 'than'", "than:"),
    ("E720", '    - try: [reach: ready]\n', r"the try of step 1 of application 'a' has no 'fallback:'", "- try:"),
    ("E720", '    - repeat: reach\n      times: 2\n',
     r"the repeat of step 1 of application 'a': 'repeat:' must be a list of steps", "- repeat:"),
    ("E721", '    - repeat: [reach: ready]\n',
     r"the repeat of step 1 of application 'a' is not bounded: it has neither times: nor until:", "- repeat:"),
    ("E721", '    - repeat: [reach: ready]\n      until: "q_m[0] > 0"\n',
     r"the repeat of step 1 of application 'a' is not bounded: it has until", "- repeat:"),
    ("E721", '    - repeat: [reach: ready]\n      times: 0\n',
     r"the repeat of step 1 of application 'a': times: must be a whole number", "times:"),
    ("E719", '    - if: "q_m[6] > 0"\n      then: [reach: ready]\n',
     r"the condition of the if of step 1 of application 'a': index \[6\] is out of range for shape \(6,\)", "q_m[6]"),
    ("E719", '    - wait: "max(q_m + EE) > 0"\n      timeout: 1 s\n',
     r"the condition of the wait of step 1 of application 'a' cannot be computed on its variables' shapes: "
     r"operands could not be broadcast", '"max(q_m + EE) > 0"'),
    ("E704", '    - if: "q_x[0] > 0"\n      then: [reach: ready]\n',
     r"the condition of the if of step 1 of application 'a' uses 'q_x', which 'variables' does not declare", "- if:"),
    ("E211", '    - try: [reech: ready]\n      fallback: [reach: ready]\n',
     r"step 1 of application 'a' runs job 'reech'", "- try:"),
])
def test_a_step_that_decides_written_wrong_is_one_located_error(tmp_path, code, steps, message, marker):
    result, path = checked(tmp_path, "  a:\n" + steps)
    assert [e.code for e in result.errors] == [code], result.errors
    [error] = result.errors
    assert re.match(message, error.message), error.message
    assert error.file == str(path) and error.line == line_of(path, marker)


@pytest.mark.parametrize("code, steps, message", [
    ("W703", "    - try: [drift: ready]\n      fallback: [reach: ready]\n", r"the try of step 1 of application 'a' cannot fail"),
    ("W704", '    - if: "1 < 2"\n      then: [reach: ready]\n',
     r"the condition of the if of step 1 of application 'a' is constant"),
    ("W705", '    - wait: "q_m[0] > 0"\n', r"the wait of step 1 of application 'a' has no timeout"),
])
def test_a_step_that_decides_suspiciously_is_warned(tmp_path, code, steps, message):
    result, _ = checked(tmp_path, "  a:\n" + steps)
    assert result.errors == []
    assert [w.code for w in result.warnings] == [code]
    assert re.match(message, result.warnings[0].message)


def test_a_try_of_a_job_with_a_pre_condition_or_a_wait_with_a_timeout_can_fail(tmp_path):
    result, _ = checked(tmp_path, '  a:\n    - try:\n        - wait: "q_m[0] > 0"\n          timeout: 1 s\n'
                                  '      fallback: [reach: ready]\n')
    assert result.errors == [] and result.warnings == []


def test_a_gap_on_one_path_makes_the_application_incomplete(tmp_path):
    result, _ = checked(tmp_path, '  a:\n    - if: "q_m[0] > 0"\n      then: [reach: ready]\n      else: [reach]\n')
    assert [w.code for w in result.warnings] == ["W701"]
    assert result.subsystem is not None
    application = result.subsystem.applications["a"]
    assert not application.complete
    assert [(g.step, g.job, g.object_type) for g in application.gaps] == [(1, "reach", "joint_position")]


def test_an_application_used_inside_a_branch_interlocks_and_takes_part_in_the_cycle_check(tmp_path):
    result, _ = checked(tmp_path, '  a:\n    - if: "q_m[0] > 0"\n      then: [b]\n  b: [a]\n')
    assert [e.code for e in result.errors] == ["E708"]
    result, _ = checked(tmp_path, '  a:\n    - try: [b: ready]\n      fallback: [reach: home]\n  b: [reach, settle]\n')
    assert result.errors == [] and [w.code for w in result.warnings] == ["W701", "W701"]  # b's gaps, filled in a
    assert result.subsystem is not None and result.subsystem.applications["a"].complete


def test_each_path_of_an_application_is_listed_with_the_jobs_it_runs():
    subsystem = load_subsystem(str(BRANCHES))
    listed, every = paths(subsystem, "pick")
    assert every == 4
    assert [(p.label, p.jobs) for p in listed] == [
        ("try: ok, repeat, if: then", ("approach", "reach", "reach", "reach", "reach", "settle")),
        ("try: ok, repeat, if: else", ("approach", "reach", "reach", "reach", "reach", "reach", "settle")),
        ("try: fails at 'approach' -> fallback, repeat, if: then", ("approach", "reach", "reach", "reach",
                                                                    "reach", "reach", "settle")),
        ("try: fails at 'approach' -> fallback, repeat, if: else",
         ("approach", "reach", "reach", "reach", "reach", "reach", "reach", "settle")),
    ]


def test_pbo_check_prints_the_switches_of_each_path(capsys):
    assert main(["check", str(BRANCHES)]) == 0
    out = capsys.readouterr().out
    assert "    path 3: try: fails at 'approach' -> fallback, repeat, if: then\n" in out
    assert "      7. settle: 'pid' -> 'pd': off pid; on pd\n" in out


def test_the_job_dictionary_describes_a_step_that_decides_with_its_rows():
    from pbo_runtime.edit.job_dictionary import job_dictionary

    steps = job_dictionary(load_subsystem(str(BRANCHES)))["applications"]["pick"]["steps"]
    assert [s["job"] for s in steps] == ["try", "repeat", "wait", "if"]
    attempt, repeat, wait, branch = (s["decision"] for s in steps)
    assert [[step["job"] for step in row] for row in attempt["rows"]] == [["approach"], ["reach"]]
    assert attempt["rows"][0][0]["object"] == "far" and repeat["times"] == 2 and wait["timeout"] == 2.0
    assert branch["condition"] == "max(abs(q_m - q_d)) < 0.005" and len(branch["rows"]) == 2
