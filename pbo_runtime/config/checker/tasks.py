"""Tasks: their fields and timing, their module and its params, and the pass over them all
(`check_tasks`); their ports are checked in `task_ports`, the devices their modules open in `task_devices`."""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, Any

from pbo_runtime.config.checker.base import CheckerBase, named_by, param_value_at
from pbo_runtime.config.checker.model import TASK_KEYS, _Link, _Task
from pbo_runtime.config.checker.task_ports import _ports_from_params
from pbo_runtime.config.checker.words import _ms, describe, did_you_mean
from pbo_runtime.config.model import Location, PortBinding, PortClaim, TaskSpec
from pbo_runtime.config.units import FREQUENCY, TIME
from pbo_runtime.config.yaml_nodes import YList, YMap, location_of, plain
from pbo_runtime.errors import ParamError
from pbo_runtime.objects.module import convert_param, param_fields
from pbo_runtime.objects.ranges import FINITE, OutOfRange


class TaskChecks(CheckerBase):
    """Rules for `tasks:`."""

    if TYPE_CHECKING:  # rules of other mixins this one calls; the whole checker has them
        def port_claim(self, value: Any, loc: Location, what: str, owner: str, allow_name: bool) -> PortClaim | None: ...
        def channels_exist(self, claim: PortClaim, what: str) -> bool: ...
        def infer_variables(self, linked: list[tuple[_Task, list[_Link]]]) -> None: ...
        def check_module_links(self, task: _Task, spec: YMap, module_class: Any) -> bool: ...
        def task_links(self, task: _Task, spec: YMap, module_class: Any) -> tuple[list[_Link], bool] | None: ...
        def bind_task_ports(self, task: _Task, links: list[_Link], ok: bool) -> bool: ...
        def report_link_mismatches(self) -> None: ...
        def check_same_shapes(self, task: _Task, spec: YMap, module_class: Any) -> bool: ...
        def check_task_devices(self, task: _Task, spec: YMap, module_class: Any) -> bool: ...

    def known_modules(self) -> list[str] | None:
        if self.module_names is None:
            return None
        try:
            return list(self.module_names())
        except Exception:  # a broken registry must not hide the user's mistake
            return None

    def check_tasks(self, top: YMap) -> None:
        # Two passes: every task's links first, so a variable no entry declares can take its type and
        # shape from all the ports that link it (`infer_variables`); then each link is checked.
        pending: list[tuple[_Task, YMap, bool, tuple[list[_Link], bool] | None]] = []
        module_class_of: dict[str, Any] = {}
        for index, (name, value, key_loc, value_loc) in enumerate(
            self.entries(top, "tasks", "task", "e.g. tasks: {pid: {module: pid_joint, rtpu: rtpu0, period: 1 ms}}")
        ):
            self.task_names.add(name)
            # (a mapping, as nearly always, needs no location and no message: they are made for the error only)
            spec = value if isinstance(value, YMap) else self.mapping(
                value, value_loc, f"task '{name}'", "e.g. pid: {module: pid_joint, rtpu: rtpu0, period: 1 ms}")
            if spec is None:
                continue
            task = _Task(name, index, key_loc)
            self.tasks[name] = task
            self.keys(spec, TASK_KEYS, ("module", "rtpu"), f"in task '{name}'", key_loc)
            complete = self.check_task_fields(task, spec)
            module_class = self.check_task_module(task, spec)
            links = None
            if module_class is not None:
                params_ok = self.check_task_params(task, spec, module_class)
                if not params_ok or not self.check_task_devices(task, spec, module_class):
                    complete = False
                # Ports made from the params (a combined module's members, a join's inputs) are unknown
                # while the params are wrong: the task is left unresolved, so no reader of what it
                # would write is told that nobody writes it (E403 is a consequence, not a mistake).
                if params_ok or not _ports_from_params(module_class):
                    links = self.task_links(task, spec, module_class)
                    if links is not None:
                        task.outputs = tuple((link.port.name, link.variable) for link in links[0] if not link.port.kind.is_input)
            module_class_of[name] = module_class
            pending.append((task, spec, complete, links))
        self.infer_variables([(task, links[0]) for task, _, _, links in pending if links is not None])
        self.var_links = {}
        self._mislinked: set[str] = set()  # the variables some port disagrees with, for report_link_mismatches
        bound = []
        for task, spec, complete, links in pending:
            if links is not None:
                task.ok = self.bind_task_ports(task, *links)
            bound.append((task, spec, complete, links))
        self.report_link_mismatches()
        for task, spec, complete, links in bound:
            if links is not None:
                if task.ok and module_class_of.get(task.name) is not None:
                    task.ok = (self.check_same_shapes(task, spec, module_class_of[task.name])
                               and self.check_module_links(task, spec, module_class_of[task.name]))
                if task.ok and "fresh_within" in spec:
                    complete = self.check_task_freshness(task, spec) and complete
            if complete and task.ok:
                self.out.tasks[task.name] = TaskSpec(
                    task.name,
                    task.module,
                    task.rtpu,
                    task.period,
                    task.priority,
                    task.critical,
                    task.params,
                    tuple([PortBinding(b.port, b.variable, b.shape) for b in task.bindings]),
                    tuple([r for r, _ in task.resources]),
                    task.index,
                    task.loc,
                    task.wcet,
                    task.aperiodic,
                    task.min_interarrival,
                    dict(task.channels),
                    {port: bound for port, (bound, _) in task.fresh_within.items()},
                )

    def check_task_fields(self, task: _Task, spec: YMap) -> bool:
        """rtpu, period/rate, priority, critical, resources; False if any is wrong."""
        ok = True
        name = task.name
        if "rtpu" in spec:
            rtpu = spec["rtpu"]  # (its location is looked up only to report it)
            if not isinstance(rtpu, str):
                self.text(rtpu, spec.value_loc("rtpu"), f"rtpu of task '{name}'")
                ok = False
            elif rtpu not in self.rtpu_names:
                self.error("E203", f"task '{name}' runs on RTPU '{rtpu}', which 'rtpus' does not declare", spec.value_loc("rtpu"),
                           did_you_mean(rtpu, self.rtpu_names, "declared"))
                ok = False
            else:
                task.rtpu = rtpu
        else:
            ok = False
        ok = self.check_task_timing(task, spec) and ok
        if "priority" in spec:
            priority = self.integer(spec["priority"], spec.value_loc("priority"), f"priority of task '{name}'")
            ok = ok and priority is not None
            task.priority = priority or 0
        if "critical" in spec:
            critical = self.boolean(spec["critical"], spec.value_loc("critical"), f"'critical' of task '{name}'")
            ok = ok and critical is not None
            task.critical = bool(critical)
        if "resources" in spec and spec["resources"] is not None:
            value = spec["resources"]
            loc = spec.value_loc("resources")
            if not isinstance(value, YList):
                self.error(
                    "E113",
                    f"resources of task '{name}' must be a list of devices, got: {describe(value)}",
                    location_of(value, loc),
                    "e.g. resources: [arm, {device: adc0, channels: 6-7}]",
                )
                return False
            seen: set[str] = set()
            for i, item in enumerate(value):
                item_loc = value.item_loc(i)
                claim = self.port_claim(item, item_loc, f"resource of task '{name}'", f"task '{name}'", allow_name=True)
                device = claim.device if claim is not None else None
                if claim is None or device is None:
                    ok = False
                elif device not in self.device_names:
                    self.error(
                        "E208",
                        f"task '{name}' uses device '{device}', which 'devices' does not declare",
                        claim.loc,
                        did_you_mean(device, self.device_names, "declared"),
                    )
                    ok = False
                elif device in seen:
                    self.error("E602", f"task '{name}' lists device '{device}' twice", item_loc)
                    ok = False
                elif device in self.out.devices and not self.channels_exist(claim, f"task '{name}'"):
                    ok = False
                else:
                    seen.add(device)
                    task.resources.append((device, item_loc))
                    if claim.channels is not None:
                        task.channels[device] = claim.channels
        return ok

    def check_task_timing(self, task: _Task, spec: YMap) -> bool:
        """period or rate, or aperiodic with min_interarrival; and wcet within the period."""
        name = task.name
        ok = True
        aperiodic = False
        if "aperiodic" in spec:
            flag = self.boolean(spec["aperiodic"], spec.value_loc("aperiodic"), f"'aperiodic' of task '{name}'")
            if flag is None:
                return False  # periodic or not is unknown: any further timing error would be a guess
            aperiodic = flag
        task.aperiodic = aperiodic
        if aperiodic:
            for key in ("period", "rate"):
                if key in spec:
                    self.error(
                        "E506",
                        f"task '{name}' is aperiodic, so it takes no {key}",
                        spec.key_loc(key),
                        "an aperiodic task runs when an event arrives; give its min_interarrival: instead (e.g. "
                        "min_interarrival: 5 ms)",
                    )
                    ok = False
            if "min_interarrival" not in spec:
                self.error(
                    "E507",
                    f"aperiodic task '{name}' needs a min_interarrival",
                    spec.key_loc("aperiodic"),
                    "add the shortest time between two of its events, e.g. min_interarrival: 5 ms",
                )
                return False
            gap = self.quantity(
                spec["min_interarrival"],
                spec.value_loc("min_interarrival"),
                TIME,
                f"min_interarrival of task '{name}'",
                longest=None,
            )
            if gap is None or not self.period_bounds(gap, spec, "min_interarrival", name):
                return False
            task.min_interarrival = gap
            task.period = gap  # the worst case: analysis treats it as periodic at its fastest
        else:
            if "min_interarrival" in spec:
                self.error(
                    "E508",
                    f"task '{name}' gives a min_interarrival but is not aperiodic",
                    spec.key_loc("min_interarrival"),
                    "add 'aperiodic: true' for a task released by events, or give a periodic task a period: or rate:",
                )
                ok = False
            if "period" in spec and "rate" in spec:
                self.error(
                    "E503",
                    f"task '{name}' gives both a period and a rate",
                    spec.key_loc("rate"),
                    "give one of them: period: 1 ms or rate: 1 kHz",
                )
                return False
            if "period" in spec:
                period = self.quantity(spec["period"], spec.value_loc("period"), TIME, f"period of task '{name}'", longest=None)
                if period is not None and not self.period_bounds(period, spec, "period", name):
                    period = None  # refused: no follow-on error from a period that is not one
                ok = ok and period is not None
                task.period = period or 0.0
            elif "rate" in spec:
                rate = self.quantity(spec["rate"], spec.value_loc("rate"), FREQUENCY, f"rate of task '{name}'")
                if rate is not None and not self.period_bounds(1.0 / rate, spec, "rate", name):
                    rate = None
                ok = ok and rate is not None
                task.period = 1.0 / rate if rate else 0.0
            else:
                self.error(
                    "E504",
                    f"task '{name}' needs a period or a rate",
                    task.loc,
                    "add e.g. 'period: 1 ms' or 'rate: 1 kHz', or 'aperiodic: true' with a min_interarrival:",
                )
                return False
        if "wcet" in spec:
            loc = spec.value_loc("wcet")
            wcet = self.quantity(spec["wcet"], loc, TIME, f"wcet of task '{name}'")
            if wcet is None:
                return False
            if ok and task.period > 0 and wcet > task.period:
                span = "min_interarrival" if aperiodic else "period"
                self.error(
                    "E505",
                    f"wcet of task '{name}' must be <= its {span} ({_ms(task.period)}), got: {spec['wcet']}",
                    loc,
                    "a cycle that runs longer than its period can never keep up; check the wcet, or slow the task down",
                )
                return False
            task.wcet = wcet
        return ok

    def check_task_module(self, task: _Task, spec: YMap) -> Any:
        if "module" not in spec:
            return None
        module = spec["module"]  # (its location is looked up only to report it)
        if not isinstance(module, str):
            self.text(module, spec.value_loc("module"), f"module of task '{task.name}'")
            return None
        task.module = module
        try:
            module_class = self.module_lookup(module)
        except Exception as exc:  # ModuleError, or a library that fails to import
            known = self.known_modules()
            hint = did_you_mean(module, known, "registered") if known is not None else str(exc)
            self.error(
                "E207", f"task '{task.name}' uses module '{module}', which is not registered", spec.value_loc("module"), hint
            )
            return None
        return module_class

    def check_task_freshness(self, task: _Task, spec: YMap) -> bool:
        """`fresh_within: {port: time}`: in-var ports of a critical task, each a time > 0."""
        name = task.name
        loc = spec.value_loc("fresh_within")
        if not task.critical:
            self.error("E511", f"task '{name}' gives fresh_within, but only a critical task watches how fresh its inputs are",
                       spec.key_loc("fresh_within"), "add 'critical: true' to the task, or remove fresh_within")
            return False
        m = self.mapping(spec["fresh_within"], loc, f"fresh_within of task '{name}'", "e.g. fresh_within: {tau_u: 3 ms}")
        if m is None:
            return False
        inputs = {b.port.name: b for b in task.bindings if b.port.kind.is_input and b.port.kind.every_cycle}
        ok = True
        for port, value in m.items():
            if port not in inputs:
                self.error(
                    "E511",
                    f"fresh_within of task '{name}' names '{port}', which is not an in-var port of module '{task.module}'",
                    m.key_loc(port),
                    did_you_mean(str(port), sorted(inputs), "in-var ports")
                    if inputs
                    else f"module '{task.module}' reads no in-var, so fresh_within has nothing to watch",
                )
                ok = False
                continue
            bound = self.quantity(value, m.value_loc(port), TIME, f"fresh_within of port '{port}' of task '{name}'")
            if bound is None:
                ok = False
                continue
            task.fresh_within[port] = (bound, m.value_loc(port))
        return ok

    def check_task_params(self, task: _Task, spec: YMap, module_class: Any) -> bool:
        raw = spec.get("params")
        if raw is not None and not isinstance(raw, YMap):
            self.error(
                "E113",
                f"params of task '{task.name}' must be a mapping, got: {describe(raw)}",
                self.params_loc(task, spec),
                "e.g. params: {kp: 400, kd: 40}",
            )
            return False
        values = plain(raw) if raw is not None else {}
        try:
            task.built_params = module_class.build_params(values)
        except OutOfRange as exc:
            element = "".join(f"[{i}]" for i in exc.index)
            self.error(
                "E308",
                f"parameter {exc.param}{element} of task '{task.name}' (module '{task.module}') must be "
                f"{exc.allowed.text()}, got: {exc.got}",
                param_value_at(spec.get("params"), exc.param, exc.index) or self.params_loc(task, spec),
                f"module '{task.module}' declares this range (pbo lexicon lists every parameter's)"
                if exc.allowed != FINITE
                else "a number parameter takes finite numbers only: not .nan, not .inf",
            )
            return False
        except ParamError as exc:
            self.error(
                "E308", f"params of task '{task.name}' (module '{task.module}'): {exc}", self.refused_at(task, spec, str(exc))
            )
            return False
        except Exception as exc:  # a module's own validation may raise anything
            self.error("E308", f"params of task '{task.name}' (module '{task.module}') were refused: {exc!r}",
                       self.refused_at(task, spec, str(exc)))
            return False
        task.params = values
        return self.check_param_lengths(task, spec, module_class)

    def check_param_lengths(self, task: _Task, spec: YMap, module_class: Any) -> bool:
        """A list parameter declared with a shape (`metadata={"shape": ("NDOF",)}`: one value per joint)
        has that many values (E308 at the parameter), which the module would otherwise refuse in init."""
        params_type = module_class.Params
        sized = self._sized_params.get(params_type)
        if sized is None:  # the fields declared with one size, found once per Params class
            try:
                declared = param_fields(params_type)
            except TypeError:  # Params is not a dataclass: nothing is declared
                declared = {}
            sized = self._sized_params[params_type] = tuple(
                (name, shape) for name, field in declared.items()
                if isinstance(shape := field.metadata.get("shape"), tuple) and len(shape) == 1)
        if not sized:
            return True
        raw = spec.get("params")
        ok = True
        for name, shape in sized:
            value = getattr(task.built_params, name, None)
            if not isinstance(value, tuple):
                continue
            size, dim = shape[0], ""
            if isinstance(size, str):
                dim = size
                size = self.out.dims.get(dim) if dim in self.out.dims else self.robot_dim(dim)
                if size is None:
                    continue  # an unknown dim is reported where a shape uses it
            if len(value) == size:
                continue
            where = raw.value_loc(name) if isinstance(raw, YMap) and name in raw else self.params_loc(task, spec)
            self.error(
                "E308",
                f"params of task '{task.name}' (module '{task.module}'): {name} must have "
                f"{size} values{f' ({dim})' if dim else ''}, got: {len(value)}",
                location_of(raw.get(name) if isinstance(raw, YMap) else None, where),
                f"give a list of {size} values"
                + (", or one number for all" if _takes_a_number(module_class.Params, name) else ""),
            )
            ok = False
        return ok

    def refused_at(self, task: _Task, spec: YMap, message: str) -> Location:
        """Where the parameter a refusal names is written (a value it quotes, as a combined module's
        wrong member 'inverse_dynamix'; a parameter it names: 'ki', PidJoint.kp, "kd must be >= 0"),
        else the params."""
        raw = spec.get("params")
        member = _member_named_by(raw, message)  # "member 2 ...": a combined module's member, and what in it
        if member is not None:
            return member
        found = named_by(raw, message) if isinstance(raw, YMap) else None
        return found or self.params_loc(task, spec)

    @staticmethod
    def params_loc(task: _Task, spec: YMap) -> Location:
        """Where a message about a task's params points: the params, or the task when it gives none."""
        return location_of(spec.get("params"), spec.value_loc("params") if "params" in spec else task.loc)


def _member_named_by(params: Any, message: str) -> Location | None:
    """Where a refusal that names a member by number ("member 2 has unknown key(s) 'param'") points:
    what it quotes inside that member, else the member itself; None when it names no member."""
    number = re.search(r"\bmembers \d+:\S+ and (\d+)\b", message) or re.search(r"\bmembers? (\d+)\b", message)  # two: the second
    members = params.get("members") if isinstance(params, YMap) else None
    if number is None or not isinstance(members, YList) or not 1 <= int(number.group(1)) <= len(members):
        return None
    index = int(number.group(1)) - 1
    node = members[index]
    inside = named_by(node, message[number.end():]) if isinstance(node, YMap) else None
    return inside or location_of(node, members.item_loc(index))



def _takes_a_number(params_type: type, name: str) -> bool:
    """Whether a parameter declared as a list also takes one number (a gain for every joint)."""
    try:
        convert_param(params_type, name, 0.0, name)
    except ParamError:
        return False
    return True
