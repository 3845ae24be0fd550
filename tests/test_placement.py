"""Placement queries: which modules can be dropped into a configuration, and the first rule the rest break.

Small subsystems of fake modules (a unit test's fakes, named as such), checked by the real checker;
then the shipped Figure 8 through `placement_report` and `pbo place`.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import ClassVar

import pytest

from pbo_runtime import ANY_DTYPE, InConst, InVar, ModuleError, OutConst, OutVar, PortBasedObject
from pbo_runtime.analysis.placement import Placement, placement_report
from pbo_runtime.cli import main
from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.config.model import Subsystem
from tests.support import REPO

# --- fake modules ----------------------------------------------------------------------------


class FakeSource(PortBasedObject):
    u = OutVar("u", shape=("N",))
    k = OutConst("k", dtype="int32")


class FakeReader(PortBasedObject):
    u = InVar("u", shape=("N",))


class FakeConstReader(PortBasedObject):
    k = InConst("k", dtype="int32")


class FakeLateK(PortBasedObject):
    """Writes k only after each cycle."""

    k = OutVar("k", dtype="int32")


class FakeSecondWriter(PortBasedObject):
    u = OutVar("u", shape=("N",))


class FakeFloat32Reader(PortBasedObject):
    u = InVar("u", dtype="float32", shape=("N",))


class FakeWideReader(PortBasedObject):
    u = InVar("u", shape=(4,))


class FakeAnyReader(PortBasedObject):
    x = InVar("nothing_defines_me", dtype=ANY_DTYPE, shape=None)


class FakeGoalConstReader(PortBasedObject):
    g = InConst("g")


class FakeNewOutput(PortBasedObject):
    y = OutVar("y_new", shape=(2,))


@dataclasses.dataclass(frozen=True)
class ArmParams:
    device: str = "arm"


class FakeArmUser(PortBasedObject):
    Params = ArmParams


@dataclasses.dataclass(frozen=True)
class CameraParams:
    device: str = "camera"


class FakeCameraUser(PortBasedObject):
    Params = CameraParams


class FakeCameraOnTheArm(PortBasedObject):
    """Opens the arm device where it needs a camera."""

    Params = ArmParams
    DEVICES: ClassVar = {"device": {"kind": "camera"}}


FAKES: dict[str, type] = {
    "source": FakeSource, "reader": FakeReader, "const_reader": FakeConstReader, "late_k": FakeLateK,
    "second_writer": FakeSecondWriter, "float32_reader": FakeFloat32Reader, "wide_reader": FakeWideReader,
    "any_reader": FakeAnyReader, "goal_const_reader": FakeGoalConstReader, "new_output": FakeNewOutput,
    "arm_user": FakeArmUser, "camera_user": FakeCameraUser, "camera_on_the_arm": FakeCameraOnTheArm,
}


def fake_lookup(name: str) -> type:
    try:
        return FAKES[name]
    except KeyError:
        raise ModuleError(f"no module named '{name}'") from None


SMALL = """\
subsystem: placing
rtpus: [rtpu0, rtpu1]
devices:
  arm: {driver: mujoco_arm, exclusive: true}
dims: {N: 3}
variables:
  g: {type: float64, object: goal}
tasks:
  src:    {module: source, rtpu: rtpu0, period: 1 ms}
  creader: {module: const_reader, rtpu: rtpu0, period: 1 ms}
  late:   {module: late_k, rtpu: rtpu1, period: 1 ms}
  arm:    {module: arm_user, rtpu: rtpu1, period: 1 ms, resources: [arm]}
  greader: {module: goal_const_reader, rtpu: rtpu0, period: 1 ms}
configurations:
  flowing: [src, creader, arm]
  late: [late]
"""


@pytest.fixture
def small(tmp_path: Path) -> Subsystem:
    path = tmp_path / "small.yaml"
    path.write_text(SMALL)
    return load_subsystem(path, fake_lookup, module_names=lambda: FAKES)


def verdict(subsystem: Subsystem, tasks: list[str], module: str, configuration: str = "flowing"):
    return Placement(subsystem, tasks, configuration, module_lookup=fake_lookup).query(module)


def test_a_module_that_breaks_no_rule_is_legal_with_its_links(small: Subsystem) -> None:
    found = verdict(small, ["src", "creader", "arm"], "reader")
    assert found.legal and found.code == ""
    assert found.links == {"u": "u"} and found.open_inputs == ()


def test_an_input_nobody_writes_yet_is_legal_and_listed_as_open(small: Subsystem) -> None:
    found = verdict(small, [], "reader")
    assert found.legal and found.open_inputs == ("u",)


def test_a_port_to_a_variable_nothing_declares_defines_it(small: Subsystem) -> None:
    found = verdict(small, ["src"], "new_output")
    assert found.legal and found.new_variables == ("y_new",)


@pytest.mark.parametrize(("tasks", "module", "code", "reason"), [
    (["src"], "source", "E407",
     "module 'source' runs already in configuration 'flowing', as task 'src' writing the same variables"),
    (["src"], "second_writer", "E401",
     "variable 'u' would have two writers in configuration 'flowing': 'src' and port 'u' of module 'second_writer'"),
    # a second instance of a module that writes nothing is no repeat (issue 22): its device decides
    (["arm"], "arm_user", "E601", "module 'arm_user' opens device 'arm', which is exclusive, and task 'arm' holds it in "
       "configuration 'flowing'"),
    ([], "camera_user", "E208", "module 'camera_user' opens device 'camera', which 'devices' does not declare"),
    ([], "camera_on_the_arm", "E610", "module 'camera_on_the_arm' needs a device of kind camera, but device 'arm' is of kind arm "
           "(driver mujoco_arm)"),
    ([], "const_reader", "E403",
     "port 'k' of module 'const_reader' reads in-const 'k', but no task in configuration 'flowing' writes it"),
    (["late"], "const_reader", "E404",
     "port 'k' of module 'const_reader' reads in-const 'k' before its init, but its writer 'late' in configuration 'flowing' "
     "writes it only after each cycle"),
    (["creader"], "late_k", "E404",
     "task 'creader' reads 'k' (port 'k') before its init, but port 'k' of module 'late_k' would write it as out-var "
     "(only after each cycle)"),
    ([], "goal_const_reader", "E405",
     "port 'g' of module 'goal_const_reader' reads in-const 'g' before its init, but in configuration 'flowing' only job control "
     "sets it, as a job's object, after tasks are spawned"),
    (["src"], "float32_reader", "E301", "port 'u' (in-var) of module 'float32_reader' is float32, but variable 'u' is float64"),
    (["src"], "wide_reader", "E302", "port 'u' (in-var) of module 'wide_reader' has shape (4,), but variable 'u' has shape (3,)"),
    ([], "any_reader", "E206",
     "port 'x' of module 'any_reader' links by default to variable 'nothing_defines_me', which nothing declares and the port "
     "cannot define"),
])
def test_each_refusal_names_the_first_rule_the_module_would_break(small: Subsystem, tasks: list[str], module: str,
                                                                  code: str, reason: str) -> None:
    found = verdict(small, tasks, module)
    assert (found.legal, found.code, found.reason) == (False, code, reason)
    assert found.hint


def test_an_exclusive_device_in_use_refuses_a_second_module_that_opens_it(small: Subsystem) -> None:
    placement = Placement(small, ["arm"], "flowing",
                          module_lookup=lambda name: FAKES["arm_user"] if name == "other_arm" else fake_lookup(name))
    found = placement.query("other_arm")
    assert (found.code, found.reason) == ("E601",
                                          "module 'other_arm' opens device 'arm', which is exclusive, and task 'arm' holds "
                                          "it in configuration 'flowing'")


def test_the_index_follows_tasks_placed_and_removed(small: Subsystem) -> None:
    placement = Placement(small, [], "", module_lookup=fake_lookup)
    assert placement.query("second_writer").legal and placement.query("arm_user").legal
    placement.add_task(small.tasks["src"])
    placement.add_task(small.tasks["arm"])
    assert placement.query("second_writer").code == "E401"
    assert placement.query("const_reader").legal
    assert placement.query("source").code == "E407" and placement.query("arm_user").code == "E601"
    placement.remove_task("src")
    placement.remove_task("arm")
    assert placement.query("second_writer").legal and placement.query("arm_user").legal
    assert placement.query("const_reader").code == "E403"


def test_the_report_is_plain_data_for_every_registered_module_of_figure_8() -> None:
    subsystem = load_subsystem(REPO / "configs" / "pid_joint.yaml")
    report = placement_report(subsystem, "joint_pid", rtpu="rtpu1")
    assert json.loads(json.dumps(report)) == report
    by_module = {m["module"]: m for m in report["modules"]}
    assert by_module["pid_joint"]["code"] == "E407"
    assert by_module["robot_position"]["code"] == "E601"
    assert by_module["gravity_compensation"]["legal"]
    assert report["legal"] == sum(m["legal"] for m in report["modules"]) and report["rtpu"] == "rtpu1"
    without_pid = placement_report(subsystem, tasks=["robot", "traj", "logger"])
    assert {m["module"]: m for m in without_pid["modules"]}["pid_joint"]["legal"]


def test_a_robot_interface_for_the_other_mode_of_the_free_arm_is_refused_as_pbo_check_would() -> None:
    subsystem = load_subsystem(REPO / "configs" / "pid_joint.yaml")  # its arm is in torque mode
    by_module = {m["module"]: m for m in placement_report(subsystem, tasks=["traj", "pid", "logger"])["modules"]}
    assert by_module["robot_torque"]["legal"]
    assert (by_module["robot_position"]["code"], by_module["robot_position"]["reason"]) == (
        "E609", "module 'robot_position' needs device 'arm' with mode: position, but the device has mode: torque")


@pytest.mark.parametrize(("arguments", "message"), [
    ({"configuration": "nope"}, "no configuration 'nope' (configurations: joint_pid)"),
    ({"rtpu": "rtpu9"}, "no RTPU 'rtpu9' (rtpus: rtpu0, rtpu1)"),
    ({"tasks": ["robot", "ghost"]}, "no task 'ghost' in subsystem 'puma'"),
])
def test_the_report_names_an_unknown_configuration_rtpu_or_task(arguments: dict, message: str) -> None:
    subsystem = load_subsystem(REPO / "configs" / "pid_joint.yaml")
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        placement_report(subsystem, **arguments)


def test_pbo_place_prints_each_module_and_exits_0_or_1_for_an_unknown_configuration(capsys: pytest.CaptureFixture[str]) -> None:
    figure_8 = str(REPO / "configs" / "pid_joint.yaml")
    assert main(["place", figure_8, "--module", "pid_joint", "--module", "gravity_compensation"]) == 0
    out = capsys.readouterr().out
    assert "configuration 'joint_pid' on rtpu0: 1 of 2 modules can be placed" in out
    assert ("no  pid_joint             [E407] module 'pid_joint' runs already in configuration 'joint_pid', "
            "as task 'pid' writing the same variables") in out
    assert "ok  gravity_compensation  (new variables: tau_g)" in out
    assert main(["place", figure_8, "--format", "json", "--tasks", "robot"]) == 0
    assert json.loads(capsys.readouterr().out)["tasks"] == ["robot"]
    assert main(["place", figure_8, "--config", "nope"]) == 1
    assert "no configuration 'nope'" in capsys.readouterr().err


def test_a_module_placed_again_is_a_second_instance_once_its_first_writes_variables_of_its_own_issue_22(small: Subsystem) -> None:
    placement = Placement(small, ["src"], "flowing", module_lookup=fake_lookup)
    assert placement.query("source").code == "E407"
    assert "link the outputs of task 'src' to variables of their own" in placement.query("source").hint
    placement.remove_task("src")
    relinked = dataclasses.replace(small.tasks["src"], bindings=tuple(
        dataclasses.replace(b, variable=f"{b.variable}_src") for b in small.tasks["src"].bindings))
    placement.add_task(relinked)
    assert placement.query("source").legal
