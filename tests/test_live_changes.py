"""Live changes (`pbo spawn/kill/replace/set/app/save`): each verb's decisions on a fake host with a
manual clock, every refusal, the refusal's text against `pbo check`'s, and `pbo save` then `pbo check`."""

from __future__ import annotations

import dataclasses
import re

import pytest

from pbo_runtime.config.loader import check_file, format_diagnostics, load_subsystem
from pbo_runtime.edit.live import LiveDescription, TaskChange, to_wire
from pbo_runtime.edit.live_save import same_subsystem
from pbo_runtime.edit.wire import from_wire
from pbo_runtime.errors import PboError
from pbo_runtime.ipc.control import BadRequest
from pbo_runtime.supervisor.commands import dispatch
from tests.fake_job_host import SUBSYSTEM, FakeJobHost, fake_subsystem

LOGGER = {"task": "logger", "module": "data_logger", "rtpu": "rtpu0", "period": "10ms",
          "params": ["variables=[q_m, tau_u]", "path=runs/live.npy"]}


@pytest.fixture
def host(tmp_path):
    return FakeJobHost(fake_subsystem(tmp_path))


def file_of(host: FakeJobHost) -> str:
    return host.subsystem.file


# --- spawn ------------------------------------------------------------------------------------


def test_a_spawned_task_is_checked_spawned_and_turned_on_at_one_cycle_boundary(host):
    reply = dispatch(host, "spawn", LOGGER)
    assert reply["state"] == "ON" and reply["entered"] == ["logger"] and reply["left"] == []
    assert host.signals[:2] == [("every RTPU", "live robot, traj, pid, pd, logger"), ("logger", "spawn")]
    (_sequence, configuration, activation), = host.plans
    assert configuration == "pid" and reply["at"] == activation
    spec = host.subsystem.tasks["logger"]
    assert spec.index == 4 and spec.params == {"variables": ["q_m", "tau_u"], "path": "runs/live.npy"}  # the first spare block
    assert host.subsystem.configurations["pid"].tasks == ("robot", "traj", "pid", "logger")
    assert host.job_control.switches[-1].change == "spawn 'logger'"


@pytest.mark.parametrize("change, refusal", [
    ({"module": None}, r"^a spawned task needs --module and --rtpu"),
    ({"task": "pid"}, r"^task 'pid' exists already \(module 'pid_joint' on rtpu0\): choose another name, or kill it first$"),
    ({"task": "bad name"},
     r"^a task's name is a letter or '_' then letters, digits or '_', at most 40 characters, got: 'bad name'$"),
    ({"module": "data_loger"},
     r"^spawning task 'logger' would break the live configuration:\n<pbo spawn logger --module>:1:1: error\[E207\]: "
         r"task 'logger' uses module 'data_loger', which is not registered\n  hint: did you mean 'data_logger'\?"),
    ({"period": "-5 ms"},
     r"^spawning task 'logger' would break the live configuration:\n<pbo spawn logger --period>:1:1: error\[E"),
    ({"period": "1e300 s"},
     r"^spawning task 'logger' would break the live configuration:\n<pbo spawn logger --period>:1:1: error\[E513\]: "
      r"period of task 'logger' must be between 10 us and 1 h, got: 1e300 s\n"),
    ({"task": "l" * 41}, r"^a task's name is a letter or '_' then letters, digits or '_', at most 40 characters, got: 'l{41}'$"),
    ({"params": ["variables=[q_m, q_x]", "path=x.npy"]},
     r"^spawning task 'logger' \(a live change cannot add a state variable: add it to the file's variables: and restart\) "
     r"would break the live configuration:\n<pbo spawn logger>:1:1: error\[E206\]: "),
    ({"params": ["variables"]}, r"^--param is given as NAME=VALUE, got: 'variables'$"),
    ({"params": ["path=a\nb"]}, r"^pbo spawn logger --param path: a value is one line of YAML"),
])
def test_a_spawn_that_is_wrong_is_refused_before_anything_is_touched(host, change, refusal):
    with pytest.raises(BadRequest, match=refusal):
        dispatch(host, "spawn", {**LOGGER, **change})
    assert host.signals == [] and host.plans == [] and "logger" not in host.subsystem.tasks


def test_a_spawned_task_opens_the_devices_given_as_its_resources_checked_like_the_files(host):
    with pytest.raises(BadRequest, match=r"E208\].*'camera'"):
        dispatch(host, "spawn", {**LOGGER, "resources": ["camera"]})
    assert "logger" not in host.subsystem.tasks
    with pytest.raises(BadRequest, match=r"E601\].*'arm'"):  # exclusive, and the robot of the running configuration holds it
        dispatch(host, "spawn", {**LOGGER, "resources": ["arm"]})
    assert "logger" not in host.subsystem.tasks and host.signals == []


def test_a_spawn_past_the_spare_status_blocks_is_refused_with_the_way_out(host):
    assert host.live is not None
    host.live = dataclasses.replace(host.live, slots=len(host.subsystem.tasks))  # no spare block left
    with pytest.raises(BadRequest, match=r"^spawning task 'logger' needs a status block in the table, but all 4 are in use "
                                         r"\(the file's tasks and the spares reserved at start\): kill a task first, or add the "
                                         r"task to the file and restart$"):
        dispatch(host, "spawn", LOGGER)


def test_a_spawn_whose_init_fails_changes_nothing_else(host):
    host.init_fails = {"logger"}
    with pytest.raises(PboError, match=r"^spawn 'logger' is refused: task 'logger' failed in init .*; nothing else changed$"):
        dispatch(host, "spawn", LOGGER)
    assert host.plans == [] and "logger" not in host.subsystem.tasks
    assert host.staged is not None and "logger" not in host.staged.tasks  # the RTPUs were given the old description back


def test_live_changes_are_refused_while_an_application_runs(host):
    host.application = "tour"
    for verb, arguments in (("spawn", LOGGER), ("kill", {"task": "pd"}), ("set", {"task": "pid", "param": "kp", "values": ["1"]}),
                            ("replace", {"task": "pid", "new": "p2"}), ("app", {"application": "tour"})):
        with pytest.raises(PboError, match=r"^application 'tour' is running its jobs; switch, job, app and live changes"):
            dispatch(host, verb, arguments)
    assert host.plans == []


# --- kill -------------------------------------------------------------------------------------


def test_a_killed_task_leaves_at_a_cycle_boundary_and_is_killed_after(host):
    dispatch(host, "spawn", LOGGER)
    reply = dispatch(host, "kill", {"task": "logger"})
    assert reply["left"] == ["logger"] and len(host.plans) == 2
    assert host.signals[-1] == ("logger", "kill") and host.task_states["logger"] == "KILLED"
    assert "logger" not in host.subsystem.tasks and reply["state"] == "KILLED"
    assert host.subsystem.configurations["pid"].tasks == ("robot", "traj", "pid")
    assert dispatch(host, "spawn", LOGGER)["state"] == "ON"  # spawned again, in the block it had
    assert host.subsystem.tasks["logger"].index == 4


def test_killing_the_only_controller_of_a_configuration_is_refused_even_when_it_is_not_running(host):
    with pytest.raises(BadRequest,
                       match=r"^killing task 'pd' would break the live configuration:\n.*error\[E408\]: configuration 'pd' "
                             r"leaves out task 'pid', which writes 'tau_u', read by 'robot'"):
        dispatch(host, "kill", {"task": "pd"})


def test_killing_the_trajectory_generator_while_the_pid_reads_q_r_is_refused_where_the_fix_goes(host):
    with pytest.raises(BadRequest) as refused:
        dispatch(host, "kill", {"task": "traj"})
    text = str(refused.value)
    pid_line = SUBSYSTEM.splitlines().index(next(line for line in SUBSYSTEM.splitlines() if line.startswith("  pid:"))) + 1
    assert re.search(rf"^{re.escape(file_of(host))}:{pid_line}:3: error\[E403\]: task 'pid' reads in-var 'q_r', but no task in "
                     rf"configuration 'pid' writes it$", text, re.M), text
    assert host.signals == [] and host.plans == [] and host.task_states["traj"] == "ON"


def test_a_refused_change_prints_the_messages_pbo_check_prints_for_the_same_file(host, tmp_path):
    with pytest.raises(BadRequest) as refused:
        dispatch(host, "kill", {"task": "traj"})
    without = (SUBSYSTEM.replace("  traj:", "  # traj:")
               .replace("[robot, traj, pid]", "[robot, pid]").replace("[robot, traj, pd]", "[robot, pd]"))
    assert without.count("# traj:") == 1
    (tmp_path / "switch_joint.yaml").write_text(without)  # the same path: the same locations
    checked = format_diagnostics(check_file(file_of(host))).splitlines()
    shown = str(refused.value).splitlines()[1:]
    assert "error[E403]" in "\n".join(checked)
    assert [line for line in shown if "error[" in line] == [line for line in checked if "error[" in line]
    assert shown[-1] == checked[-1].split(",")[0] + ", 0 warnings"  # the count line: errors as pbo check counts them


def test_killing_a_task_that_is_not_there_is_a_bad_request(host):
    with pytest.raises(BadRequest, match=r"^no task 'nope' \(tasks: robot, traj, pid, pd\)$"):
        dispatch(host, "kill", {"task": "nope"})


# --- replace ----------------------------------------------------------------------------------


def test_a_replaced_task_hands_over_to_the_new_one_in_one_switch(host):
    reply = dispatch(host, "replace", {"task": "pid", "new": "pd2", "params": ["ki=0", "kp=500"]})
    assert reply["left"] == ["pid"] and reply["entered"] == ["pd2"] and len(host.plans) == 1
    assert host.task_states["pd2"] == "ON" and host.task_states["pid"] == "KILLED"
    new = host.subsystem.tasks["pd2"]
    assert (new.module, new.rtpu, new.period) == ("pid_joint", "rtpu0", 0.001)  # the old entry's, where not given
    assert new.params == {"kp": 500, "kd": 40, "ki": 0, "gravity_feedforward": True}
    assert host.subsystem.configurations["pid"].tasks == ("robot", "traj", "pd2")
    assert list(host.subsystem.tasks) == ["robot", "traj", "pd2", "pd"]  # in the old one's place


@pytest.mark.parametrize("arguments, refusal", [
    ({"task": "pid", "new": "pd"}, r"^task 'pd' exists already"),
    ({"task": "nope", "new": "x"}, r"^no task 'nope'"),
    ({"task": "pid", "new": "p2", "module": "joint_trajectory"},
     r"^replacing task 'pid' by 'p2' would break the live configuration:\n"),
])
def test_a_replace_that_is_wrong_is_refused(host, arguments, refusal):
    with pytest.raises(BadRequest, match=refusal):
        dispatch(host, "replace", arguments)
    assert host.plans == [] and host.task_states["pid"] == "ON"


# --- a parameter's range, at every live door ----------------------------------------------------


@pytest.mark.parametrize("value, shown", [("1.0e+308", r"1e\+308"), (".nan", r"\.nan \(not a number\)"), ("-.inf", r"-\.inf")])
@pytest.mark.parametrize("verb, arguments, where, task", [
    ("set", {"task": "pid", "param": "kp"}, "<pbo set pid kp>", "pid"),
    ("replace", {"task": "pid", "new": "pd2"}, "<pbo replace pid pd2 --param kp>", "pd2"),
    ("spawn", {**LOGGER, "task": "pid2", "module": "pid_joint", "params": ["ki=0"], "ports": ["tau=tau_u"]},
     "<pbo spawn pid2 --param kp>", "pid2"),
])
def test_a_parameter_out_of_its_range_is_refused_with_the_same_words_at_every_live_door(host, verb, arguments, where, task,
                                                                                         value, shown):
    if verb == "set":
        arguments = {**arguments, "values": [value]}
    else:
        arguments = {**arguments, "params": [*arguments.get("params", []), f"kp={value}"]}
    with pytest.raises(BadRequest, match=rf"\n{re.escape(where)}:1:1: error\[E308\]: parameter kp of task '{task}' "
                                         rf"\(module 'pid_joint'\) must be in \[0, 1e\+06\], got: {shown}\n"):
        dispatch(host, verb, arguments)
    assert host.plans == [] and host.subsystem.tasks["pid"].params["kp"] == 400


# --- set --------------------------------------------------------------------------------------


def test_a_tunable_parameter_is_set_at_a_cycle_boundary(host):
    reply = dispatch(host, "set", {"task": "pid", "param": "kp", "values": ["300"]})
    assert reply["value"] == 300 and host.subsystem.tasks["pid"].params["kp"] == 300 and len(host.plans) == 1
    assert reply["entered"] == reply["left"] == []
    dispatch(host, "set", {"task": "pid", "param": "kd", "values": ["1", "2", "3", "4", "5", "6"]})
    assert host.subsystem.tasks["pid"].params["kd"] == [1, 2, 3, 4, 5, 6]


@pytest.mark.parametrize("arguments, refusal", [
    ({"param": "gravity_feedforward", "values": ["false"]},
     r"^parameter 'gravity_feedforward' of task 'pid' is not live-tunable: module 'pid_joint' reads it in init only "
     r"\(live-tunable: kp, kd, ki\); to change it, replace the task: pbo replace pid NEW --param gravity_feedforward=...$"),
    ({"param": "kdd", "values": ["1"]}, r"^module 'pid_joint' of task 'pid' has no parameter 'kdd': did you mean 'kd'\? "),
    ({"param": "kq", "values": ["1"]}, r"^module 'pid_joint' of task 'pid' has no parameter 'kq' \(parameters: kp, kd, ki, "
                                       r"bandwidth, damping, integral_time, integral_limit, gravity_feedforward; "
                                       r"live-tunable: kp, kd, ki\)$"),
    ({"param": "kd", "values": ["40", "40", "40", "40", "40", "250"]},
     r"^setting 'kd' of task 'pid' would break the live configuration:\n<pbo set pid kd \(value 6\)>:1:1: error\[E326\]: the "
     r"position loop of joint 6 \(joint6\) under task 'pid' \(kp 400, kd 250, ki 10\) is unstable at inertia 0\.1941 kg m² .*\n"
     r"  hint: stable for kd < 19\d\.?\d* \(at kp 400\)"),
    ({"param": "bandwidth", "values": ["30"]}, r"^parameter 'bandwidth' of task 'pid' is not live-tunable"),
    *[({"param": "kp", "values": [value]},
       rf"^setting 'kp' of task 'pid' would break the live configuration:\n<pbo set pid kp>:1:1: error\[E308\]: parameter kp of "
       rf"task 'pid' \(module 'pid_joint'\) must be in \[0, 1e\+06\], got: {shown}\n")
      for value, shown in [("-3", "-3"), ("1.0e+308", r"1e\+308"), (".nan", r"\.nan \(not a number\)"), (".inf", r"\.inf")]],
    ({"param": "kp", "values": ["1", "2", ".nan", "4", "5", "6"]},
     r"<pbo set pid kp \(value 3\)>:1:1: error\[E308\]: parameter kp\[2\] of task 'pid' \(module 'pid_joint'\) must be in "
     r"\[0, 1e\+06\], got: \.nan \(not a number\)"),
    ({"param": "kp", "values": ["fast"]}, r"^setting 'kp' of task 'pid' would break the live configuration:\n.*error\[E308\]: "),
    ({"param": "kp", "values": []}, r"^pbo set pid kp needs a value$"),
])
def test_a_set_that_is_wrong_is_refused_naming_what_may_be_set(host, arguments, refusal):
    with pytest.raises(BadRequest, match=refusal):
        dispatch(host, "set", {"task": "pid", **arguments})
    assert host.plans == [] and host.subsystem.tasks["pid"].params["kp"] == 400


# --- app ----------------------------------------------------------------------------------------


def test_an_application_is_started_on_the_live_subsystem(host):
    reply = dispatch(host, "app", {"application": "tour"})
    assert host.started_applications == ["tour"] and reply["jobs"] == ["reach", "settle", "reach"]


def test_an_unknown_application_is_a_bad_request(host):
    with pytest.raises(BadRequest, match=r"^no application 'nope' \(applications: tour\)$"):
        dispatch(host, "app", {"application": "nope"})


# --- save ---------------------------------------------------------------------------------------


def test_save_then_check_gives_the_live_subsystem_back_with_the_comments_kept(host, tmp_path):
    dispatch(host, "spawn", LOGGER)
    dispatch(host, "set", {"task": "pid", "param": "kp", "values": ["300"]})
    dispatch(host, "replace", {"task": "pid", "new": "pd2", "params": ["ki=0"]})
    dispatch(host, "kill", {"task": "logger"})
    saved = tmp_path / "saved" / "live.yaml"
    saved.parent.mkdir()
    reply = dispatch(host, "save", {"file": str(saved)})
    assert reply["edits"] == 4 and "WARNING" not in reply["message"]
    text = saved.read_text()
    assert "# Dynamic reconfiguration on the arm (TR §4.4)" in text and "# yaml-language-server" in text
    original = SUBSYSTEM.splitlines(keepends=True)
    untouched = [line for line in original if not line.startswith(("  pid:", "          params: {kp: 400"))]
    assert [line for line in text.splitlines(keepends=True) if line in original] == untouched  # as written, in order
    result = check_file(saved)
    assert result.ok, format_diagnostics(result)
    assert result.subsystem is not None and same_subsystem(result.subsystem, host.subsystem)
    assert list(result.subsystem.tasks) == ["robot", "traj", "pd2", "pd"]


@pytest.mark.parametrize("file, refusal", [("relative.yaml", r"^the file to write must be an absolute path"),
                                           (None, r"^the file to write must be given as text")])
def test_save_refuses_a_file_it_cannot_name(host, file, refusal):
    with pytest.raises(BadRequest, match=refusal):
        dispatch(host, "save", {"file": file})


def test_save_does_not_overwrite_without_force(host, tmp_path):
    target = tmp_path / "exists.yaml"
    target.write_text("keep me")
    with pytest.raises(BadRequest, match=r"exists: give --force to overwrite it$"):
        dispatch(host, "save", {"file": str(target)})
    assert target.read_text() == "keep me"
    dispatch(host, "save", {"file": str(target), "force": True})
    assert check_file(target).ok


# --- what RTPUs are sent ------------------------------------------------------------------------


def test_the_live_description_an_rtpu_reads_is_the_one_job_control_checked(tmp_path):
    subsystem = load_subsystem(fake_subsystem(tmp_path).file)
    live = LiveDescription.start(subsystem, 8).replace("pid", "pd2", TaskChange(params={"ki": "0"}))
    back = from_wire(subsystem, to_wire(live.subsystem))
    def located_nowhere(tasks):
        return {name: dataclasses.replace(spec, loc=None) for name, spec in tasks.items()}

    assert located_nowhere(back.tasks) == located_nowhere(live.subsystem.tasks)
    assert back.configurations.keys() == live.subsystem.configurations.keys()
    assert all(back.configurations[n].tasks == c.tasks for n, c in live.subsystem.configurations.items())


def test_an_aperiodic_task_can_be_spawned_with_its_shortest_interarrival(host):
    dispatch(host, "spawn", {**LOGGER, "period": None, "aperiodic": True, "min_interarrival": "20ms"})
    spec = host.subsystem.tasks["logger"]
    assert spec.aperiodic and spec.min_interarrival == pytest.approx(0.02)


def test_a_live_description_directory_a_dead_run_left_is_removed_and_a_live_runs_is_kept(tmp_path):
    import os

    from pbo_runtime.supervisor.live_changes import remove_dead_live_dirs

    dead = tmp_path / "pbo-live-999999999-abc123-x1y2"  # no such pid
    alive = tmp_path / f"pbo-live-{os.getpid()}-abc123-x1y2"
    other = tmp_path / "pbo-live-notarun"
    for folder in (dead, alive, other):
        folder.mkdir()
    (dead / "live-1.json").write_text("{}")
    assert remove_dead_live_dirs(str(tmp_path)) == [str(dead)]
    assert not dead.exists() and alive.exists() and other.exists()
