"""The reconfiguration plan between consecutive jobs, as `pbo check` shows it (TR §4.4)."""

from __future__ import annotations

from pbo_runtime import InVar, OutVar, PortBasedObject
from pbo_runtime.config.loader import check_file
from pbo_runtime.config.transitions import flatten, transitions


class FakeSensor(PortBasedObject):
    x = OutVar("x")


class FakeController(PortBasedObject):
    x = InVar("x")
    goal = InVar("goal")
    u = OutVar("u")


class FakeActuator(PortBasedObject):
    u = InVar("u")


LIBRARY = {"sensor": FakeSensor, "controller": FakeController, "actuator": FakeActuator}

TEXT = """\
subsystem: plan
rtpus: [rtpu0]
variables:
  x: {type: float64}
  goal: {type: float64, object: setpoint}
  u: {type: float64}
tasks:
  sensor: {module: sensor, rtpu: rtpu0, period: 1 ms}
  ik:     {module: controller, rtpu: rtpu0, period: 1 ms}
  dls:    {module: controller, rtpu: rtpu0, period: 1 ms}
  arm:    {module: actuator, rtpu: rtpu0, period: 1 ms}
configurations:
  with_ik:  [sensor, ik, arm]
  with_dls: [sensor, dls, arm]
jobs:
  approach: {configuration: with_ik, object: goal}
  track:    {configuration: with_dls, object: goal}
applications:
  reach: [{approach: {goal: 1.0}}, {track: {goal: 2.0}}]
  twice: [reach, {approach: {goal: 0.0}}]
"""


def load(tmp_path):
    path = tmp_path / "plan.yaml"
    path.write_text(TEXT)
    result = check_file(path, module_lookup=LIBRARY.__getitem__, module_names=lambda: sorted(LIBRARY))
    assert result.errors == [], [e.format() for e in result.errors]
    return result.subsystem


def test_switching_controllers_turns_the_leaving_off_and_the_entering_on(tmp_path):
    plan = transitions(load(tmp_path), "reach")
    assert [(t.job, t.before, t.after, t.off, t.on, t.stay) for t in plan] == [
        ("approach", None, "with_ik", (), ("sensor", "ik", "arm"), ()),
        ("track", "with_ik", "with_dls", ("ik",), ("dls",), ("sensor", "arm")),
    ]


def test_an_application_used_as_a_step_is_expanded_in_place(tmp_path):
    subsystem = load(tmp_path)
    assert flatten(subsystem, "twice") == ["approach", "track", "approach"]
    assert transitions(subsystem, "twice")[-1].off == ("dls",)
