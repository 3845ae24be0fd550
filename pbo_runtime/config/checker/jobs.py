"""Job control: jobs, their conditions (expressions), and applications made of job steps."""

from __future__ import annotations

import dataclasses
import graphlib
import re
from typing import TYPE_CHECKING, Any

import numpy as np

from pbo_runtime.config.checker.base import CheckerBase
from pbo_runtime.config.checker.decisions import StepDraft as _Step
from pbo_runtime.config.checker.decisions import decision_kind, used_applications
from pbo_runtime.config.checker.model import JOB_KEYS, NO_OBJECT
from pbo_runtime.config.checker.words import _show_shape, describe, did_you_mean
from pbo_runtime.config.expressions import ALLOWED, Condition, ExpressionError, compile_condition
from pbo_runtime.config.model import NOWHERE, ApplicationSpec, ApplicationStep, Gap, JobSpec, Location, ObjectTypeSpec
from pbo_runtime.config.units import TIME
from pbo_runtime.config.yaml_nodes import YList, YMap, location_of, plain


class JobChecks(CheckerBase):
    """Rules for `jobs:` and `applications:`."""

    if TYPE_CHECKING:  # rules of other mixins this one calls; the whole checker has them
        def check_value(self, value: Any, loc: Location, dtype: str, shape: tuple[int, ...], what: str,
                        owner: str = "the variable's shape", kind: ObjectTypeSpec | None = None) -> np.ndarray | None: ...
        def check_object_names(self) -> None: ...
        def objects_of_type(self, type_name: str | None) -> str: ...
        def job_written(self) -> set[str]: ...
        def check_decision(self, app: str, number: int, item: YMap, kind: str) -> _Step | None: ...
        def finish_decision(self, app: str, number: int, item: _Step, gaps: list[Gap]) -> ApplicationStep | None: ...

    def check_expression(self, value: Any, loc: Location, what: str) -> str | None:
        """A job condition in the restricted language of `config.expressions`, naming declared variables."""
        text = self.text(value, loc, what)
        if text is None:
            return None
        example = 'e.g. "max(abs(q_m - q_d)) < 1e-3"'
        try:
            condition = compile_condition(text)
        except ExpressionError as exc:
            where = self.inside_scalar(loc, text, exc.offset)
            if exc.syntax:
                self.error("E702", f"{what} is not an expression: {exc.message}: {text!r}", where, example)
            elif exc.too_large:
                self.error("E710", f"{what}: {exc.message} (column {exc.offset + 1} of {text!r})", where,
                           "a condition compares measured values; write a float (1e30) for a huge number")
            else:
                self.error(
                    "E703",
                    f"{what}: {exc.message} (column {exc.offset + 1} of {text!r})",
                    where,
                    f"a condition may use {ALLOWED}",
                )
            return None
        self.expression_names.update(condition.variables)
        unknown = sorted(condition.variables - set(self.var_locs))
        for name in unknown:
            offset = _name_offset(text, name)
            self.error(
                "E704",
                f"{what} uses '{name}', which 'variables' does not declare",
                self.inside_scalar(loc, text, offset),
                did_you_mean(name, self.var_locs, "declared"),
            )
        if unknown:
            return None
        return text if self.condition_computes(condition, text, loc, what) else None

    def condition_computes(self, condition: Condition, text: str, loc: Location, what: str) -> bool:
        """E719 unless the condition computes on values of its variables' dtypes and shapes: an index
        past a variable's shape (`q_m[6]` on 6 joints), shapes that do not combine (`q_m - EE`) fail
        every evaluation, so the job would fail each time it ran. Evaluated once, on zeros."""
        specs = self.out.variables
        if not all(name in specs for name in condition.variables):
            return True  # a variable is wrong itself (reported there): its shape is not known
        zeros = {name: np.broadcast_to(np.zeros((), dtype=specs[name].dtype), specs[name].shape) for name in condition.variables}
        shapes = ", ".join(f"{name} {specs[name].dtype} {_show_shape(specs[name].shape)}" for name in sorted(condition.variables))
        try:
            with np.errstate(all="ignore"):
                condition.evaluate(zeros)
        except ExpressionError as exc:
            self.error("E719", f"{what}: {exc.message} (column {exc.offset + 1} of {text!r})",
                       self.inside_scalar(loc, text, exc.offset), f"the variables it reads: {shapes}")
            return False
        except (ValueError, TypeError, IndexError) as exc:  # numpy: shapes that do not broadcast
            self.error("E719", f"{what} cannot be computed on its variables' shapes: {exc} ({text!r})", loc,
                       f"the variables it reads: {shapes}")
            return False
        return True

    def inside_scalar(self, loc: Location, text: str, offset: int) -> Location:
        """Where character `offset` of a one-line scalar `text` written at `loc` is, if the file shows it.

        The YAML node's location is its first character: the quote of a quoted scalar. Escapes
        or a block scalar make the written text differ from the value; then `loc` it is.
        """
        line = self.source_line(loc)
        if line is None or "\n" in text:
            return loc
        start = loc.column - 1
        for skip in (1, 0) if line[start:start + 1] in ("'", '"') else (0,):
            if line[start + skip:start + skip + len(text)] == text:
                return Location(loc.file, loc.line, loc.column + skip + offset)
        return loc

    def source_line(self, loc: Location) -> str | None:
        if loc.file not in self.sources:
            try:
                with open(loc.file, encoding="utf-8-sig") as stream:
                    self.sources[loc.file] = stream.read().splitlines()
            except (OSError, UnicodeError):
                self.sources[loc.file] = []
        lines = self.sources[loc.file]
        return lines[loc.line - 1] if 0 < loc.line <= len(lines) else None

    def check_jobs(self, top: YMap) -> None:
        for name, value, key_loc, value_loc in self.entries(
            top, "jobs", "job", "e.g. jobs: {move: {configuration: joint_pid, object: q_d}}"
        ):
            self.job_names.add(name)
            spec = self.mapping(value, value_loc, f"job '{name}'", "e.g. move: {configuration: joint_pid, object: q_d}")
            if spec is None:
                continue
            self.keys(spec, JOB_KEYS, ("configuration",), f"in job '{name}'", key_loc)
            ok = "configuration" in spec
            config = None
            if "configuration" in spec:
                loc = spec.value_loc("configuration")
                config = self.text(spec["configuration"], loc, f"configuration of job '{name}'")
                if config is not None and config not in self.config_names:
                    self.error(
                        "E210",
                        f"job '{name}' runs configuration '{config}', which 'configurations' does not declare",
                        loc,
                        did_you_mean(config, self.config_names, "declared"),
                    )
                    ok = False
                ok = ok and config is not None
            obj = None
            written = "object" in spec and spec["object"] is not None  # `object: null` is left out, like every key
            if written:
                loc = spec.value_loc("object")
                obj = self.text(spec["object"], loc, f"object of job '{name}'")
                if obj is None or obj == NO_OBJECT:
                    pass  # not text (reported), or `object: none`: the job is an action
                elif obj not in self.var_locs:
                    self.error(
                        "E213",
                        f"job '{name}' takes object '{obj}', which 'variables' does not declare",
                        loc,
                        did_you_mean(obj, self.var_object or self.var_locs, "objects"),
                    )
                    ok = False
                elif obj not in self.var_object:
                    self.error(
                        "E701",
                        f"job '{name}' takes variable '{obj}' as its object, but the variable is not marked as an object",
                        loc,
                        f"add 'object: <type>' to variable '{obj}' (line {self.var_locs[obj].line})",
                    )
                    ok = False
                ok = ok and obj is not None
            if ok and config is not None:
                obj = self.job_object(name, config, obj if written else None, spec.value_loc("object") if written else key_loc)
                ok = obj != ""
            if obj == NO_OBJECT:
                obj = None
            pre = post = None
            if "pre" in spec and spec["pre"] is not None:
                pre = self.check_expression(spec["pre"], spec.value_loc("pre"), f"pre-condition of job '{name}'")
                ok = ok and pre is not None
            if "post" in spec and spec["post"] is not None:
                post = self.check_expression(spec["post"], spec.value_loc("post"), f"post-condition of job '{name}'")
                ok = ok and post is not None
            timeout = None
            if "timeout" in spec and spec["timeout"] is not None:
                timeout = self.quantity(spec["timeout"], spec.value_loc("timeout"), TIME, f"timeout of job '{name}'")
                ok = ok and timeout is not None
            if ok and config is not None:
                kind = self.var_object.get(obj) if obj is not None else None
                self.out.jobs[name] = JobSpec(name, config, obj, pre, post, timeout, key_loc, kind)

    def job_object(self, job: str, config: str, written: str | None, loc: Location) -> str | None:
        """The variable a job's object goes to: inferred from its configuration's tasks (Onika §4.3.3).

        A task needs user input when it reads a variable marked `object:` that no task of the
        configuration writes: job control writes it, from the object the job is given. `written`
        is the job's own `object:` (None if left out, NO_OBJECT for `object: none`), checked against
        that. Returns the variable, None (an action), or "" after an error.
        """
        members = [self.tasks.get(t) for t, _ in self.config_members.get(config, [])]
        if any(task is None or not task.ok for task in members):
            # a task's ports are unknown, so what it reads is too (reported at the task): no
            # inferred class, lest the steps that give the job an object be refused as well
            return "" if written is None else written
        outputs = {
            b.variable: task.name for task in members if task is not None for b in task.bindings if not b.port.kind.is_input
        }
        needed: dict[str, str] = {}  # object variable -> the first task that reads it
        for task in members:
            assert task is not None
            for b in task.bindings:
                if b.port.kind.is_input and b.variable in self.var_object and b.variable not in outputs:
                    needed.setdefault(b.variable, task.name)
        need = ", ".join(f"'{v}' (type {self.var_object[v]}, read by '{t}')" for v, t in needed.items())
        if written == NO_OBJECT:
            return NO_OBJECT
        if written is not None:
            touched = {b.variable for task in members if task is not None for b in task.bindings}
            if written in needed or written in touched:
                return written  # an out-var takes over the value it finds when it is turned on, too
            unwritten = {b.variable for task in members if task is not None for b in task.bindings
                         if b.port.kind.is_input and b.variable not in outputs} - self.job_written()
            if unwritten:
                return written  # the configuration is broken itself (E403 there): what it needs is not known
            self.error(
                "E715",
                f"job '{job}' takes object '{written}', but no task of configuration '{config}' reads or writes it",
                loc,
                f"its tasks need {need}: write that, or leave object: out to infer it"
                if needed
                else "its tasks need no object: remove object:, and the job is an action",
            )
            return ""
        if len(needed) > 1:
            self.error("E716", f"job '{job}' needs more than one object: configuration '{config}' reads {need}, "
                               "but a job takes one", loc,
                       f"choose the one its steps give with object: <variable> (the others keep their value), "
                       f"or object: {NO_OBJECT}")
            return ""
        return next(iter(needed), None)

    def check_applications(self, top: YMap) -> None:
        """Steps interlock (Onika §4.4.1-4.4.2); applications nest without cycles; gaps make them incomplete."""
        entries: list[tuple[str, Location, Any, Location]] = []
        for name, value, key_loc, value_loc in self.entries(
            top, "applications", "application", "e.g. applications: {demo: [move, {move: home}]}"
        ):
            if name in self.job_names:
                self.error(
                    "E214",
                    f"'{name}' names both a job and an application",
                    key_loc,
                    "a step names a job or an application, so their names must differ; rename one",
                )
                continue
            self.app_names.add(name)
            entries.append((name, key_loc, value, value_loc))
        self.check_object_names()
        parsed: dict[str, tuple[list[_Step], Location]] = {}
        for name, key_loc, value, loc in entries:
            if not isinstance(value, YList):
                self.error(
                    "E113",
                    f"application '{name}' must be a list of job steps, got: {describe(value)}",
                    location_of(value, loc),
                    f"e.g. {name}: [move, {{move: home}}]",
                )
                continue
            steps: list[_Step] = []
            ok = True
            for i, item in enumerate(value):
                checked = self.check_step(name, i + 1, item, value.item_loc(i))
                if checked is None:
                    ok = False
                    continue
                steps.append(checked)
            if ok:
                parsed[name] = (steps, key_loc)
        graph = {name: {used for s in steps for used in used_applications(s)} for name, (steps, _) in parsed.items()}
        order = self.application_order(graph, {name: loc for name, _, _, loc in entries}, {name: k for name, k, _, _ in entries})
        for name in order:
            steps, key_loc = parsed[name]
            built: list[ApplicationStep] = []
            gaps: list[Gap] = []
            ok = True
            for number, item in enumerate(steps, 1):
                step = item.step
                if step.decision is not None:
                    decided = self.finish_decision(name, number, item, gaps)
                    ok = ok and decided is not None
                    built.extend([decided] if decided is not None else [])
                    continue
                if not step.is_application:
                    built.append(step)
                    if item.gap is not None:
                        gaps.append(Gap(number, step.job, item.gap))
                    continue
                inner = self.out.applications.get(step.job)
                if inner is None:
                    ok = False  # it is wrong itself, and was reported there
                    continue
                if item.given is not None:
                    filled = self.fill_application(name, number, inner, item)
                    if filled is None:
                        ok = False
                        continue
                    built.append(filled)
                    continue
                built.append(step)
                if inner.gaps:
                    gaps.append(Gap(number, step.job, inner.object_type))
                    fix = (
                        f"give it an object of type {inner.object_type} ('- {step.job}: "
                        f"<object>') or fill the gaps of '{step.job}'"
                        if inner.object_type
                        else f"fill the gaps of '{step.job}' first"
                    )
                    self.warn(
                        "W702",
                        f"application '{name}' is incomplete: step {number} '{step.job}' "
                        f"is the incomplete application '{step.job}'",
                        step.loc,
                        f"{fix}; an incomplete application may be kept but not run",
                    )
            if ok:
                self.out.applications[name] = ApplicationSpec(name, tuple(built), key_loc, not gaps, tuple(gaps))

    def fill_application(self, app: str, number: int, inner: ApplicationSpec, item: _Step) -> ApplicationStep | None:
        """A step giving an object to an application: one object of the one type of its gaps fills them all (Onika §4.4.2)."""
        step, given, given_loc = item.step, item.given, item.given_loc
        if not inner.gaps:
            self.error(
                "E709",
                f"step {number} of application '{app}' gives objects to application '{step.job}', which takes none",
                location_of(given, given_loc),
                f"application '{step.job}' is complete: it has no gap to fill; write '- {step.job}'",
            )
            return None
        kind = inner.object_type
        if kind is None:
            kinds = sorted({str(g.object_type) for g in _inner_gaps(self.out.applications, step.job)})
            where = ", ".join(f"step {g.step} '{g.job}' ({g.object_type or 'several'})" for g in inner.gaps)
            self.error(
                "E718",
                f"step {number} of application '{app}' gives an object to application '{step.job}', whose gaps need "
                f"objects of types {', '.join(kinds)}: no one object fills them ({where})",
                location_of(given, given_loc),
                f"give the objects to the steps inside application '{step.job}'",
            )
            return None
        if isinstance(given, str):
            return self.named_object(app, number, step.job, "application", kind, given, given_loc, step)
        m = self.mapping(given, given_loc, f"object of application '{step.job}' in application '{app}'",
                         f"e.g. - {step.job}: <object name>, or - {step.job}: {{{kind}: <value>}}")
        if m is None:
            return None
        keys = list(m)
        if len(keys) != 1 or keys[0] != kind:
            wrong = keys[1] if len(keys) > 1 else keys[0] if keys else None
            self.error(
                "E706" if len(keys) > 1 else "E707",
                f"step {number} of application '{app}' gives {', '.join(str(k) for k in keys) or 'nothing'} to application "
                f"'{step.job}', whose gaps take one object of type {kind}",
                m.key_loc(wrong) if wrong is not None else location_of(m, given_loc),
                f"write '- {step.job}: {{{kind}: <value>}}', or name an object of type {kind}: {self.objects_of_type(kind)}",
            )
            return None
        value = m[kind]
        if isinstance(value, str):
            return self.named_object(app, number, step.job, "application", kind, value, m.value_loc(kind), step)
        object_type = self.out.object_types[kind]
        array = self.check_value(
            value,
            m.value_loc(kind),
            object_type.dtype,
            object_type.shape,
            f"object of step {number} of application '{app}'",
            f"the shape of object type '{kind}'",
            object_type,
        )
        if array is None:
            return None
        return dataclasses.replace(step, fill=plain(value))

    def named_object(self, app: str, number: int, target: str, what: str, kind: str | None, name: str, loc: Location,
                     step: ApplicationStep) -> ApplicationStep | None:
        """A step that gives a named object: it exists, and its type is the one the job or application needs."""
        obj = self.out.objects.get(name)
        if kind in self.bad_object_types:
            return None  # the type itself is wrong, and was reported there
        if obj is None:
            if name in self.object_locs:
                return None  # the object is wrong itself, and was reported there
            fitting = [o.name for o in self.out.objects.values() if o.type == kind]
            self.error("E714", f"step {number} of application '{app}' gives object '{name}' to {what} '{target}', "
                               "but 'objects' declares no such object", loc,
                       did_you_mean(name, fitting, f"objects of type {kind}") if fitting
                       else f"declare it: objects: {{{name}: {{type: {kind}, value: <value>}}}}")
            return None
        if obj.type != kind:
            self.error("E713", f"step {number} of application '{app}' gives object '{name}' of type {obj.type} to {what} "
                               f"'{target}', which needs an object of type {kind}", loc,
                       f"objects of type {kind}: {self.objects_of_type(kind)}")
            return None
        return dataclasses.replace(step, object=name)

    def application_order(
        self, graph: dict[str, set[str]], locs: dict[str, Location], key_locs: dict[str, Location]
    ) -> list[str]:
        """Applications with the ones they use first; those on a cycle are reported and left out."""
        known = {name: {s for s in subs if s in graph} for name, subs in graph.items()}
        sorter = graphlib.TopologicalSorter(known)
        try:
            return list(sorter.static_order())
        except graphlib.CycleError as exc:
            cycle: list[str] = list(reversed(exc.args[1]))  # graphlib lists it from user to used
            self.error(
                "E708",
                f"applications form a cycle: {' -> '.join(cycle)}",
                key_locs.get(cycle[0], locs.get(cycle[0], NOWHERE)),
                "an application may use another as a step, but never itself, directly or through others",
            )
            on_cycle = set(cycle)
            rest = {n: subs for n, subs in known.items() if n not in on_cycle}
            # whatever uses a broken application cannot be built either
            changed = True
            while changed:
                changed = False
                for n in list(rest):
                    if rest[n] - set(rest):
                        del rest[n]
                        changed = True
            return self.application_order(rest, locs, key_locs) if rest else []

    def check_step(self, app: str, number: int, item: Any, loc: Location) -> _Step | None:
        """One step as far as it can be checked before the applications it uses are: None if it is wrong."""
        args: Any = None
        args_loc = loc
        decides = decision_kind(item)
        if decides is not None:
            return self.check_decision(app, number, item, decides)
        if isinstance(item, str):
            job = item
        elif isinstance(item, YMap) and len(item) == 1:
            key = next(iter(item))
            job_name = self.text(key, item.key_loc(key), f"job of step {number} of application '{app}'")
            if job_name is None:
                return None
            job = job_name
            loc = item.key_loc(key)
            args = item[key]
            args_loc = item.value_loc(key)
        else:
            self.error(
                "E113",
                f"step {number} of application '{app}' must be a job name or {{job: object}}, got: {describe(item)}",
                location_of(item, loc),
                "e.g. - move: home, or - move: {q_d: [0, -0.5, 0.5, 0, 0, 0]}",
            )
            return None
        if job not in self.job_names and job in self.app_names:
            return _Step(ApplicationStep(job, {}, loc, is_application=True), None, args, args_loc)
        if job not in self.job_names:
            self.error("E211", f"step {number} of application '{app}' runs job '{job}', which 'jobs' does not declare", loc,
                       did_you_mean(job, self.job_names | self.app_names, "jobs and applications"))
            return None
        spec = self.out.jobs.get(job)
        if spec is None:
            return None  # the job itself is wrong, and was reported there
        step = ApplicationStep(job, {}, loc)
        kind = spec.object_type
        if isinstance(args, str):
            if spec.object is None:
                self.error(
                    "E705",
                    f"step {number} of application '{app}' gives object '{args}' to job '{job}', which takes no object",
                    args_loc,
                    f"write '- {job}', or give job '{job}' an object: in 'jobs'",
                )
                return None
            named = self.named_object(app, number, job, "job", kind, args, args_loc, step)
            return None if named is None else _Step(named, None)
        arguments: dict[str, Any] = {}
        if args is not None:
            m = self.mapping(
                args,
                args_loc,
                f"arguments of job '{job}' in application '{app}'",
                f"e.g. - {job}: home, or - {job}: {{q_d: [0, 0, 0]}}",
            )
            if m is None:
                return None
            names = list(m)
            if names and spec.object is None:
                self.error(
                    "E705",
                    f"step {number} of application '{app}' gives object '{names[0]}' to job '{job}', which takes no object",
                    m.key_loc(names[0]),
                    f"remove the object, or give job '{job}' an object: in 'jobs'",
                )
                return None
            if len(names) > 1:
                self.error(
                    "E706",
                    f"step {number} of application '{app}' gives {len(names)} objects to job '{job}' "
                    f"({', '.join(str(n) for n in names)}), but a job takes exactly one",
                    m.key_loc(names[1]),
                    f"job '{job}' takes its object '{spec.object}' (type {kind}); give only that one",
                )
                return None
            for var, val in m.items():
                if var != spec.object:
                    self.error(
                        "E707",
                        f"step {number} of application '{app}' gives '{var}' to job '{job}', but "
                        f"its object is '{spec.object}' (type {kind})",
                        m.key_loc(var),
                        f"write '- {job}: {{{spec.object}: <value>}}', or name an object of type {kind}: "
                        f"{self.objects_of_type(kind)}",
                    )
                    return None
                variable = self.out.variables.get(str(var))
                if variable is None:
                    return None  # the job's own object is wrong, and was reported there
                if isinstance(val, str):
                    named = self.named_object(app, number, job, "job", kind, val, m.value_loc(var), step)
                    return None if named is None else _Step(named, None)
                array = self.check_value(
                    val,
                    m.value_loc(var),
                    variable.dtype,
                    variable.shape,
                    f"object '{var}' of step {number} of application '{app}'",
                    kind=self.out.object_types.get(variable.object or ""),
                )
                if array is None:
                    return None
                arguments[str(var)] = plain(val)
        gap = bool(spec.object) and spec.object not in arguments
        if gap:
            self.warn(
                "W701",
                f"application '{app}' is incomplete: step {number} '{job}' needs an object of type {kind}",
                loc,
                f"give it as '- {job}: <object>' (of type {kind}: {self.objects_of_type(kind)}) "
                f"or '- {job}: {{{spec.object}: <value>}}'; an incomplete application may be kept but not run",
            )
        return _Step(dataclasses.replace(step, arguments=arguments), kind if gap else None)


def _inner_gaps(applications: dict[str, ApplicationSpec], name: str) -> list[Gap]:
    """The gaps of an application and, for a gap that is an incomplete application, its own (for a message)."""
    spec = applications.get(name)
    if spec is None:
        return []
    found: list[Gap] = []
    for gap in spec.gaps:
        found.extend(_inner_gaps(applications, gap.job) if gap.object_type is None else [gap])
    return found


def _name_offset(text: str, name: str) -> int:
    """Where `name` first appears in `text` as a whole word; 0 if it cannot be found."""
    match = re.search(rf"(?<![A-Za-z0-9_]){re.escape(name)}(?![A-Za-z0-9_])", text)
    return match.start() if match else 0
