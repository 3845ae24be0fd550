"""Joint position loops: a joint-space controller's gains against the arm it drives, before it runs.

For each task with joint gains (a module whose parameters have `kp`, `kd` and `bandwidth`: `pid_joint`),
or member of a `combined` task with them (at the combined task's period), whose torque goes to a
robot in torque mode, each joint's loop is analysed as a sampled double
integrator over the joint's inertia range (`objects.joint_loop`, `objects.arm_inertia`): the loop
is sampled at the slower of the controller's and the robot interface's periods, with one period of
delay between the measurement and the torque. A loop unstable somewhere in the workspace is an
error (E326) at the gain, naming the joint, the inertia, the gain and the bound that would make it
stable; a ringing one (damping ratio under 0.3) a warning (W301); so is a goal the controller is given directly
whose step asks more torque than the joint's limit (W302). Giving a bandwidth and raw gains at once
is E325. `pbo set` re-checks the file with the new gain, so it refuses an unstable one in the same
words. The gains a bandwidth makes are said with the robot's notes (`pbo check`, `pbo run`).

A controller whose output is the acceleration inverse dynamics reads (a module with an
`ACCELERATION_INPUT`, as a task or as a member of a combined task) whose torque goes to such a robot
is a computed-torque loop: the model cancels each joint's inertia, so the gains act on a unit
inertia, with the delay the configuration adds between the two (none when the inverse dynamics runs
after the controller in the same cycle: later in the same combined task, or on the same RTPU at the
same period and ahead in the order the executive runs them; a period otherwise). A bandwidth given
to such a controller is W303: it makes torque gains, which the inverse dynamics scales again.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pbo_runtime.config.checker.base import CheckerBase, param_value_at
from pbo_runtime.config.checker.plant_arm import describe_plant_arm
from pbo_runtime.config.limits import MAX_PERIOD, MIN_PERIOD
from pbo_runtime.config.model import Location
from pbo_runtime.config.yaml_nodes import YList, YMap
from pbo_runtime.objects.arm import ROBOT_OPTIONS, Arm
from pbo_runtime.objects.joint_loop import LOW_DAMPING, LoopGains, analyse

RAW_GAINS = ("kp", "kd", "ki")
#: How a note saying the gains a bandwidth made begins (`pbo status` and the run report pick them out).
GAINS_NOTE = "gains of task"
BANDWIDTH_KEYS = ("bandwidth", "damping", "integral_time")
#: Periods of delay between the sample a controller reads and its torque reaching the arm: the robot
#: interface applies a command the cycle after it measured what the command answers (on either clock).
DELAY = 1


@dataclass(frozen=True)
class _Controller:
    """A joint-space controller with gains: a task's module, or a member of a combined task."""

    task: Any  # the task it runs in: its period, its name
    who: str  # how a message names it: task 'pid', or member 1 (pid_joint) of task 'ctc'
    params: Any  # its built params
    given: dict[str, Any]  # its params as written
    node: Any  # the YAML map they are written in (where a gain is), or None
    outputs: tuple[str, ...]  # the table variables it writes
    reference: str | None  # the table variable its q_r reads; None when a member of its task computes it
    gains_of: str = ""  # how the note of the gains a bandwidth made names it, when not as `who`
    writes: tuple[str, ...] = ()  # a member: every variable it writes as its links name them (those kept local too)
    member: int = -1  # a member: its place in its combined task


@dataclass(frozen=True)
class _InverseDynamics:
    """A module turning a joint acceleration into torque through the arm's model: a task, or a member."""

    task: Any
    who: str
    reads: str  # the variable its acceleration port reads, as its links name it
    reads_table: str | None  # that variable in the table; None when a member of its task writes it
    outputs: tuple[str, ...]  # the table variables it writes
    member: int = -1


@dataclass(frozen=True)
class _Loop:
    """A controller's loops on a torque-mode robot: directly, or through inverse dynamics."""

    controller: _Controller
    period: float  # the slowest of the tasks on the way
    delay: int  # periods between the measurement and the torque
    through: _InverseDynamics | None = None
    late: str = ""  # why the inverse dynamics reads the controller's acceleration a period late


class JointLoopChecks(CheckerBase):
    """E325, E326, W301, W302, W303: the joint loops of the subsystem's torque-mode robots."""

    def check_joint_loops(self, top: YMap) -> None:
        """Every joint-space controller's loops, for every robot interface in torque mode it drives."""
        nodes = top.get("tasks")
        if not isinstance(nodes, YMap):
            return
        controllers = self._controllers(nodes)
        if not controllers:
            return
        torque_readers = self._torque_robots_by_variable()
        dynamics = self._inverse_dynamics()
        looped: list[_Loop] = []
        for controller in controllers:
            if not self._one_kind_of_gains(controller):
                continue
            robots = _robots_reading(controller.outputs, torque_readers, controller.task.name)
            if robots and _periods_valid(controller.task.period, *robots):
                looped.append(_Loop(controller, max(controller.task.period, *robots), DELAY))
            for stage in dynamics:
                late = self._feeds(controller, stage)
                robots = _robots_reading(stage.outputs, torque_readers, stage.task.name) if late is not None else []
                if late is not None and robots and _periods_valid(controller.task.period, stage.task.period, *robots):
                    looped.append(_Loop(controller, max(controller.task.period, stage.task.period, *robots),
                                        DELAY + bool(late), stage, late))
        if not looped:
            return
        robot = self._arm_of_plant()
        if robot is None:
            return
        from pbo_runtime.objects.arm_inertia import arm_gains, inertia_range  # Pinocchio: only when there is a loop

        inertia = inertia_range(robot.arm, robot.ee)
        for loop in looped:
            controller = loop.controller
            p, task = controller.params, controller.task
            if p.bandwidth > 0:
                kp, kd, ki, _ = arm_gains(inertia, p.bandwidth, p.damping, p.integral_time, task.period)
                note = (f"gains of {controller.gains_of or controller.who}: "
                        f"bandwidth {p.bandwidth:g} rad/s, damping {p.damping:g}"
                        + (f", integral time {p.integral_time:g} s" if p.integral_time else "")
                        + f" make kp {_numbers(kp)}, kd {_numbers(kd)}" + (f", ki {_numbers(ki)}" if np.any(ki) else ""))
                if note not in self.out.robot_notes:
                    self.out.robot_notes.append(note)
                if loop.through is not None:
                    self._bandwidth_through_inverse_dynamics(loop, np.sqrt(kp))
            else:
                n = robot.arm.shape[0]
                raw = [np.asarray(getattr(p, k), dtype=float).reshape(-1) for k in RAW_GAINS]
                if any(g.size not in (1, n) for g in raw):
                    continue  # a list of another length than the joints: E308 at the gain
                kp, kd, ki = (np.broadcast_to(g, (n,)) for g in raw)
            for joint, name in enumerate(robot.joint_names):
                gains = LoopGains(float(kp[joint]), float(kd[joint]), float(ki[joint]))
                self._check_loop(loop, joint, name, gains, float(inertia.coupled_low[joint]), float(inertia.high[joint]),
                                 robot.arm[joint], float(robot.q0[joint]))

    def _controllers(self, nodes: YMap) -> list[_Controller]:
        """The tasks with joint gains, and the members with them of combined tasks."""
        found = []
        for task in self.tasks.values():
            if not task.ok:
                continue
            node = nodes.get(task.name)
            params = node.get("params") if isinstance(node, YMap) else None
            if _has_joint_gains(task.built_params):
                outputs = tuple(b.variable for b in task.bindings if not b.port.kind.is_input)
                found.append(_Controller(task, f"task '{task.name}'", task.built_params, task.params, params, outputs,
                                         next((b.variable for b in task.bindings if b.port.name == "q_r"), None),
                                         writes=outputs))
            found.extend(self._members_with_gains(task, params))
        return found

    @staticmethod
    def _members_with_gains(task: Any, params: Any) -> list[_Controller]:
        """The members of a combined task with joint gains: what each writes and reads of the table."""
        members = getattr(task.built_params, "built", None)
        if not members:
            return []
        table_variable = {b.port.name: b.variable for b in task.bindings}  # a combined task's ports are named by variable
        internal = task.built_params.internal_variables()
        written = task.params.get("members")
        nodes = params.get("members") if isinstance(params, YMap) else None
        found = []
        for index, member in enumerate(members):
            if not _has_joint_gains(member.params):
                continue
            entry = nodes[index] if isinstance(nodes, YList) and index < len(nodes) else None
            node = entry.get("params") if isinstance(entry, YMap) else None
            given = written[index].get("params") if isinstance(written, list) and isinstance(written[index], dict) else None
            outputs = tuple(table_variable[v] for port, v in member.links if not port.kind.is_input and v in table_variable)
            reference = next((v for port, v in member.links if port.name == "q_r"), None)
            number, module = member.name.split(":", 1)
            found.append(_Controller(task, f"member {number} ({module}) of task '{task.name}'", member.params, dict(given or {}),
                                     node if isinstance(node, YMap) else None, outputs,
                                     None if reference is None or reference in internal else table_variable.get(reference),
                                     f"task '{task.name}', member {number} ({module})",
                                     tuple(v for port, v in member.links if not port.kind.is_input), index))
        return found

    def _inverse_dynamics(self) -> list[_InverseDynamics]:
        """The tasks and members of combined tasks that turn a joint acceleration into torque (`ACCELERATION_INPUT`)."""
        found = []
        for task in self.tasks.values():
            if not task.ok:
                continue
            members = getattr(task.built_params, "built", None)
            if members:
                table_variable = {b.port.name: b.variable for b in task.bindings}
                internal = task.built_params.internal_variables()
                for index, member in enumerate(members):
                    port = getattr(member.cls, "ACCELERATION_INPUT", "")
                    reads = next((v for p, v in member.links if p.name == port), None) if port else None
                    if reads is None:
                        continue
                    number, module = member.name.split(":", 1)
                    found.append(_InverseDynamics(
                        task, f"member {number} ({module}) of task '{task.name}'", reads,
                        None if reads in internal else table_variable.get(reads),
                        tuple(table_variable[v] for p, v in member.links if not p.kind.is_input and v in table_variable), index))
                continue
            try:
                port = getattr(self.module_lookup(task.module), "ACCELERATION_INPUT", "")
            except Exception:  # an unknown module is reported where the task is checked
                continue
            reads = next((b.variable for b in task.bindings if port and b.port.name == port), None)
            if reads is not None:
                found.append(_InverseDynamics(task, f"task '{task.name}'", reads, reads,
                                              tuple(b.variable for b in task.bindings if not b.port.kind.is_input)))
        return found

    def _feeds(self, controller: _Controller, stage: _InverseDynamics) -> str | None:
        """None when `controller` does not write what `stage` reads (or they never run together); else why
        `stage` reads it a period late, or "" when it reads it in the same cycle."""
        if stage.task is controller.task:
            if controller.member < 0 or stage.member < 0 or stage.reads not in controller.writes:
                return None
            return "" if controller.member < stage.member else (
                f"{stage.who} reads '{stage.reads}' of the cycle before: it is listed before the controller, so runs first")
        if stage.reads_table is None or stage.reads_table not in controller.outputs:
            return None
        writer, reader = controller.task, stage.task
        configurations = [{name for name, _ in members} for members in self.config_members.values()]
        if not any(writer.name in names and reader.name in names for names in configurations):
            return None
        why = f"{stage.who} reads '{stage.reads_table}' of the cycle before"
        if writer.rtpu != reader.rtpu:
            return f"{why}: it runs on another RTPU"
        if writer.period != reader.period:
            return f"{why}: it runs at another period"
        if writer.critical != reader.critical:
            return "" if writer.critical else f"{why}: it is critical, so runs first"
        if writer.priority != reader.priority:
            return "" if writer.priority > reader.priority else f"{why}: its priority is higher, so it runs first"
        order = self.out.init_order  # equal tasks run in the order they came on: the init order, one switch at a time
        if writer.name in order and reader.name in order and order.index(writer.name) > order.index(reader.name):
            return f"{why}: it comes before '{writer.name}' in the init order, so runs first"
        alone = next((c for c, members in self.config_members.items()
                      if reader.name in {n for n, _ in members} and writer.name not in {n for n, _ in members}), None)
        if alone is not None:
            return f"{why}: configuration '{alone}' runs it without '{writer.name}', which comes on after it"
        return ""

    def _one_kind_of_gains(self, controller: _Controller) -> bool:
        """E325: a bandwidth and raw gains at once (the module would use only one)."""
        given, params = controller.given, controller.node
        raw = [k for k in RAW_GAINS if k in given]
        if not raw or "bandwidth" not in given:
            return True
        loc = param_value_at(params, raw[0]) or controller.task.loc
        self.error("E325", f"{controller.who} gives both a bandwidth and raw gains ({', '.join(raw)}): the bandwidth "
                           f"makes each joint's gains from the arm's inertia, so the raw ones would be ignored", loc,
                   f"give either bandwidth (with damping, integral_time) or {', '.join(RAW_GAINS)}; remove {', '.join(raw)}",
                   [(param_value_at(params, "bandwidth") or controller.task.loc, "the bandwidth is given here")])
        return False

    def _torque_robots_by_variable(self) -> dict[str, list[Any]]:
        """variable -> the robot interface tasks in torque mode (tasks opening a torque-mode device) that read it."""
        readers: dict[str, list[Any]] = {}
        for task in self.tasks.values():
            if task.ok and task.resources and any(self._torque_device(d) for d, _ in task.resources):
                for b in task.bindings:
                    if b.port.kind.is_input:
                        readers.setdefault(b.variable, []).append(task)
        return readers

    def _torque_device(self, name: str) -> bool:
        device = self.out.devices.get(name)
        return device is not None and device.options.get("mode") == "torque"

    def _arm_of_plant(self) -> Any:
        """The plant's robot as the plant would load it (its ARM, EE and joint names), or None."""
        spec = self.out.plant
        if spec is None:
            return None
        known = getattr(self, "described_robot", None)
        if known is not None and hasattr(known, "arm"):
            return known
        try:
            base_dir = Path(spec.loc.file).resolve().parent if spec.loc.file else Path.cwd()
            options = {k: v for k, v in spec.options.items() if k in ROBOT_OPTIONS}
            return describe_plant_arm(spec.type, spec.model, base_dir, options)
        except Exception:  # a robot that does not load is reported where the plant is checked
            return None

    def _check_loop(self, loop: _Loop, joint: int, name: str, gains: LoopGains, low: float, high: float,
                    row: np.ndarray, start: float) -> None:
        controller, through = loop.controller, loop.through
        bandwidth = controller.params.bandwidth > 0
        where = self._gain_at(controller, "bandwidth" if bandwidth else "kd", joint)
        what = (f"joint {joint + 1} ({name}) under {controller.who} (kp {gains.kp:.4g}, kd {gains.kd:.4g}"
                + (f", ki {gains.ki:.4g}" if gains.ki else "")
                + (f", from bandwidth {controller.params.bandwidth:g} rad/s" if bandwidth else "") + ")")
        if through is None:
            workspace = f"from {low:.4g} with the other joints free to {high:.4g} kg m² over the workspace"
        else:
            what += f" through the inverse dynamics of {through.who}"
            workspace = f"computed torque cancels its {low:.4g} to {high:.4g} kg m², not its viscous friction"
        fix = ("lower the bandwidth (pbo robot MODEL --bandwidth W --period T prints each joint's gains and verdict)"
               if bandwidth else "or give bandwidth: and damping: instead of raw gains (pbo robot MODEL --bandwidth W "
               "prints each joint's)")
        if through is not None:
            fix = ("under computed torque the gains are accelerations: kp = w², kd = 2 ζ w for a bandwidth w "
                   + ("(bandwidth: makes torques for the arm's inertia, which the inverse dynamics multiplies by it again)"
                      if bandwidth else "(pbo robot's gains are torques)"))
        viscous = float(row[Arm.DAMPING])
        verdict = analyse(low, high, gains, loop.period, loop.delay, viscous, computed_torque=through is not None)
        sampled = (f"sampled every {loop.period * 1e3:g} ms with "
                   + ("one period of delay" if loop.delay == 1 else f"{loop.delay} periods of delay")
                   + (f" ({loop.late})" if loop.late else ""))
        if not verdict.stable:
            at = " as a unit inertia" if through is not None else f" at inertia {verdict.worst_inertia:.4g} kg m²"
            self.error("E326", f"the position loop of {what} is unstable{at} ({workspace}), {sampled}: a pole at "
                               f"|z| = {verdict.spectral_radius:.3g} > 1", where,
                       fix if bandwidth else f"{verdict.bound_text(gains)}; {fix}")
            return
        if verdict.damping < LOW_DAMPING:
            self.warn("W301", f"the position loop of {what} rings: damping ratio {verdict.damping:.2f} < {LOW_DAMPING:g} "
                              + (f"somewhere {workspace}" if through is None else f"as a unit inertia ({workspace})")
                              + f", {sampled}",
                      where, "raise kd towards 2 sqrt(kp I), or give bandwidth: and damping: 1.0" if through is None
                      else f"raise kd towards 2 sqrt(kp); {fix}")
        self._check_step_torque(loop, joint, name, gains, row, start, high)

    def _bandwidth_through_inverse_dynamics(self, loop: _Loop, bandwidths: np.ndarray) -> None:
        """W303: a bandwidth makes torque gains for each joint's inertia (kp = I w²); the inverse dynamics
        multiplies the PID's output by the inertia again, so each joint gets sqrt(kp), not w."""
        controller, p = loop.controller, loop.controller.params
        assert loop.through is not None
        wanted = p.bandwidth
        self.warn("W303", f"{controller.who} is given bandwidth {wanted:g} rad/s but drives the arm through the inverse "
                          f"dynamics of {loop.through.who}: a bandwidth makes torques for each joint's inertia, which the "
                          f"inverse dynamics multiplies by the inertia again: the joints get {_numbers(bandwidths)} rad/s",
                  self._gain_at(controller, "bandwidth", 0),
                  f"under computed torque the gains are accelerations: give kp: {wanted * wanted:.4g}, kd: "
                  f"{2 * p.damping * wanted:.4g} (kp = w², kd = 2 ζ w) instead of bandwidth:")

    def _check_step_torque(self, loop: _Loop, joint: int, name: str, gains: LoopGains, row: np.ndarray,
                           start: float, high: float) -> None:
        """W302: a goal the controller reads as it is (no task writes its reference) whose step from the
        robot's start asks kp * step past the joint's effort limit (under computed torque, times the
        joint's heaviest inertia): the command saturates."""
        controller = loop.controller
        reference = controller.reference
        if reference is None:
            return
        goal = self.out.initial_values.get(reference)
        if goal is None or any(reference == v for t in self.tasks.values() for _, v in t.outputs):
            return
        values = np.asarray(goal, dtype=float).reshape(-1)
        step = abs(float(values[joint] if values.size > joint else values[0]) - start)
        inertia = 1.0 if loop.through is None else high
        torque, effort = gains.kp * step * inertia, float(row[Arm.EFFORT])
        if torque > effort:
            asks = (f"kp {gains.kp:.4g} x {step:.4g} = {torque:.4g}" if loop.through is None else
                    f"kp {gains.kp:.4g} x {step:.4g} x {inertia:.4g} kg m² = {torque:.4g} (through the inverse dynamics)")
            self.warn("W302", f"the goal of joint {joint + 1} ({name}) is {step:.4g} from the start: {controller.who} "
                              f"asks {asks} at once, past the effort limit {effort:g}",
                      self._gain_at(controller, "bandwidth" if controller.params.bandwidth > 0 else "kp", joint),
                      "put a joint_trajectory between the goal and the controller, or lower the gain")

    @staticmethod
    def _gain_at(controller: _Controller, key: str, joint: int) -> Location:
        """Where the gain of `joint` is written (its element of a list), else the params, else the task."""
        params = controller.node
        return (param_value_at(params, key, (joint,)) or param_value_at(params, key)
                or (params.loc if isinstance(params, YMap) else controller.task.loc))


def _periods_valid(*periods: float) -> bool:
    """Whether every period on a loop's way is one a task may have: one out of bounds is E513 already."""
    return all(MIN_PERIOD <= period <= MAX_PERIOD for period in periods)


def _robots_reading(variables: tuple[str, ...], readers: dict[str, list[Any]], writer: str) -> list[float]:
    """The periods of the torque-mode robot interfaces (other than `writer`) that read any of `variables`."""
    robots = {r.name: r.period for v in variables for r in readers.get(v, ()) if r.name != writer}
    return list(robots.values())


def _has_joint_gains(params: Any) -> bool:
    return params is not None and all(hasattr(params, k) for k in (*RAW_GAINS, *BANDWIDTH_KEYS))


def _numbers(values: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:.4g}" for v in values) + "]"
