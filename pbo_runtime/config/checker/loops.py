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
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pbo_runtime.config.checker.base import CheckerBase, param_value_at
from pbo_runtime.config.checker.plant_arm import describe_plant_arm
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


class JointLoopChecks(CheckerBase):
    """E325, E326, W301, W302: the joint loops of the subsystem's torque-mode robots."""

    def check_joint_loops(self, top: YMap) -> None:
        """Every joint-space controller's loops, for every robot interface in torque mode it drives."""
        nodes = top.get("tasks")
        if not isinstance(nodes, YMap):
            return
        controllers = self._controllers(nodes)
        if not controllers:
            return
        torque_readers = self._torque_robots_by_variable()
        looped = []
        for controller in controllers:
            if not self._one_kind_of_gains(controller):
                continue
            robots = {r.name: r for v in controller.outputs for r in torque_readers.get(v, ())}
            robots.pop(controller.task.name, None)
            if robots:
                looped.append((controller, max(r.period for r in robots.values())))
        if not looped:
            return
        robot = self._arm_of_plant()
        if robot is None:
            return
        from pbo_runtime.objects.arm_inertia import arm_gains, inertia_range  # Pinocchio: only when there is a loop

        inertia = inertia_range(robot.arm, robot.ee)
        for controller, robot_period in looped:
            p, task = controller.params, controller.task
            period = max(task.period, robot_period)
            if p.bandwidth > 0:
                kp, kd, ki, _ = arm_gains(inertia, p.bandwidth, p.damping, p.integral_time, task.period)
                self.out.robot_notes.append(
                    f"gains of {controller.gains_of or controller.who}: bandwidth {p.bandwidth:g} rad/s, damping {p.damping:g}"
                    + (f", integral time {p.integral_time:g} s" if p.integral_time else "")
                    + f" make kp {_numbers(kp)}, kd {_numbers(kd)}" + (f", ki {_numbers(ki)}" if np.any(ki) else ""))
            else:
                n = robot.arm.shape[0]
                raw = [np.asarray(getattr(p, k), dtype=float).reshape(-1) for k in RAW_GAINS]
                if any(g.size not in (1, n) for g in raw):
                    continue  # a list of another length than the joints: E308 at the gain
                kp, kd, ki = (np.broadcast_to(g, (n,)) for g in raw)
            for joint, name in enumerate(robot.joint_names):
                gains = LoopGains(float(kp[joint]), float(kd[joint]), float(ki[joint]))
                self._check_loop(controller, joint, name, gains, float(inertia.coupled_low[joint]), float(inertia.high[joint]),
                                 period, robot.arm[joint], float(robot.q0[joint]))

    def _controllers(self, nodes: YMap) -> list[_Controller]:
        """The tasks with joint gains, and the members with them of combined tasks."""
        found = []
        for task in self.tasks.values():
            if not task.ok:
                continue
            node = nodes.get(task.name)
            params = node.get("params") if isinstance(node, YMap) else None
            if _has_joint_gains(task.built_params):
                found.append(_Controller(task, f"task '{task.name}'", task.built_params, task.params, params,
                                         tuple(b.variable for b in task.bindings if not b.port.kind.is_input),
                                         next((b.variable for b in task.bindings if b.port.name == "q_r"), None)))
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
                                     f"task '{task.name}', member {number} ({module})"))
        return found

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

    def _check_loop(self, controller: _Controller, joint: int, name: str, gains: LoopGains, low: float, high: float,
                    period: float, row: np.ndarray, start: float) -> None:
        bandwidth = controller.params.bandwidth > 0
        where = self._gain_at(controller, "bandwidth" if bandwidth else "kd", joint)
        what = (f"joint {joint + 1} ({name}) under {controller.who} (kp {gains.kp:.4g}, kd {gains.kd:.4g}"
                + (f", ki {gains.ki:.4g}" if gains.ki else "")
                + (f", from bandwidth {controller.params.bandwidth:g} rad/s" if bandwidth else "") + ")")
        workspace = f"from {low:.4g} with the other joints free to {high:.4g} kg m² over the workspace"
        fix = ("lower the bandwidth (pbo robot MODEL --bandwidth W --period T prints each joint's gains and verdict)"
               if bandwidth else "or give bandwidth: and damping: instead of raw gains (pbo robot MODEL --bandwidth W "
               "prints each joint's)")
        viscous = float(row[Arm.DAMPING])
        verdict = analyse(low, high, gains, period, DELAY, viscous)
        sampled = f"sampled every {period * 1e3:g} ms with one period of delay"
        if not verdict.stable:
            self.error("E326", f"the position loop of {what} is unstable at inertia {verdict.worst_inertia:.4g} kg m² "
                               f"({workspace}), {sampled}: a pole at |z| = {verdict.spectral_radius:.3g} > 1", where,
                       fix if bandwidth else f"{verdict.bound_text(gains)}; {fix}")
            return
        if verdict.damping < LOW_DAMPING:
            self.warn("W301", f"the position loop of {what} rings: damping ratio {verdict.damping:.2f} < {LOW_DAMPING:g} "
                              f"somewhere {workspace}, {sampled}",
                      where, "raise kd towards 2 sqrt(kp I), or give bandwidth: and damping: 1.0")
        self._check_step_torque(controller, joint, name, gains, row, start)

    def _check_step_torque(self, controller: _Controller, joint: int, name: str, gains: LoopGains, row: np.ndarray,
                           start: float) -> None:
        """W302: a goal the controller reads as it is (no task writes its reference) whose step from the
        robot's start asks kp * step past the joint's effort limit: the command saturates."""
        reference = controller.reference
        if reference is None:
            return
        goal = self.out.initial_values.get(reference)
        if goal is None or any(reference == v for t in self.tasks.values() for _, v in t.outputs):
            return
        values = np.asarray(goal, dtype=float).reshape(-1)
        step = abs(float(values[joint] if values.size > joint else values[0]) - start)
        torque, effort = gains.kp * step, float(row[Arm.EFFORT])
        if torque > effort:
            self.warn("W302", f"the goal of joint {joint + 1} ({name}) is {step:.4g} from the start: {controller.who} "
                              f"asks kp {gains.kp:.4g} x {step:.4g} = {torque:.4g} at once, past the effort limit {effort:g}",
                      self._gain_at(controller, "bandwidth" if controller.params.bandwidth > 0 else "kp", joint),
                      "put a joint_trajectory between the goal and the controller, or lower the gain")

    @staticmethod
    def _gain_at(controller: _Controller, key: str, joint: int) -> Location:
        """Where the gain of `joint` is written (its element of a list), else the params, else the task."""
        params = controller.node
        return (param_value_at(params, key, (joint,)) or param_value_at(params, key)
                or (params.loc if isinstance(params, YMap) else controller.task.loc))


def _has_joint_gains(params: Any) -> bool:
    return params is not None and all(hasattr(params, k) for k in (*RAW_GAINS, *BANDWIDTH_KEYS))


def _numbers(values: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:.4g}" for v in values) + "]"
