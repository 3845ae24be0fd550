"""Job control: jobs, their conditions (expressions), and applications made of job steps."""

from __future__ import annotations

import graphlib
import re
from typing import TYPE_CHECKING, Any

from pbo_runtime.config.checker.base import CheckerBase
import numpy as np
from pbo_runtime.config.checker.model import JOB_KEYS
from pbo_runtime.config.checker.words import describe, did_you_mean
from pbo_runtime.config.model import NOWHERE, ApplicationSpec, ApplicationStep, JobSpec, Location
from pbo_runtime.config.expressions import ALLOWED, ExpressionError, compile_condition
from pbo_runtime.config.units import TIME
from pbo_runtime.config.yaml_nodes import YList, YMap, location_of, plain


class JobChecks(CheckerBase):
    """Rules for `jobs:` and `applications:`."""

    if TYPE_CHECKING:  # rules of other mixins this one calls; the whole checker has them
        def check_value(self, value: Any, loc: Location, dtype: str, shape: tuple[int, ...], what: str) -> np.ndarray | None: ...

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
        return None if unknown else text

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
        for name, value, key_loc, value_loc in self.entries(top, "jobs", "job", "e.g. jobs: {move: {configuration: joint_pid, object: q_d}}"):
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
                    self.error("E210", f"job '{name}' runs configuration '{config}', which 'configurations' does not declare", loc, did_you_mean(config, self.config_names, "declared"))
                    ok = False
                ok = ok and config is not None
            obj = None
            if "object" in spec and spec["object"] is not None:
                loc = spec.value_loc("object")
                obj = self.text(spec["object"], loc, f"object of job '{name}'")
                if obj is not None and obj not in self.var_locs:
                    self.error("E213", f"job '{name}' takes object '{obj}', which 'variables' does not declare", loc, did_you_mean(obj, self.var_object or self.var_locs, "objects"))
                    ok = False
                elif obj is not None and obj not in self.var_object:
                    self.error(
                        "E701",
                        f"job '{name}' takes variable '{obj}' as its object, but the variable is not marked as an object",
                        loc,
                        f"add 'object: <type>' to variable '{obj}' (line {self.var_locs[obj].line})",
                    )
                    ok = False
                ok = ok and obj is not None
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
                self.out.jobs[name] = JobSpec(name, config, obj, pre, post, timeout, key_loc)

    def check_applications(self, top: YMap) -> None:
        """Steps interlock (Onika §4.4.1-4.4.2); applications nest without cycles; gaps make them incomplete."""
        entries: list[tuple[str, Location, Any, Location]] = []
        for name, value, key_loc, value_loc in self.entries(top, "applications", "application", "e.g. applications: {demo: [move, {move: {q_d: [0, 0, 0]}}]}"):
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
        parsed: dict[str, tuple[list[ApplicationStep], set[int], Location]] = {}
        for name, key_loc, value, loc in entries:
            if not isinstance(value, YList):
                self.error("E113", f"application '{name}' must be a list of job steps, got: {describe(value)}", location_of(value, loc), f"e.g. {name}: [move, {{move: {{q_d: [0, 0, 0]}}}}]")
                continue
            steps: list[ApplicationStep] = []
            gaps: set[int] = set()  # step numbers whose job lacks its object
            ok = True
            for i, item in enumerate(value):
                checked = self.check_step(name, i + 1, item, value.item_loc(i))
                if checked is None:
                    ok = False
                    continue
                step, gap = checked
                steps.append(step)
                if gap:
                    gaps.add(i + 1)
            if ok:
                parsed[name] = (steps, gaps, key_loc)
        graph = {name: {s.job for s in steps if s.is_application} for name, (steps, _, _) in parsed.items()}
        order = self.application_order(graph, {name: loc for name, _, _, loc in entries}, {name: k for name, k, _, _ in entries})
        complete: dict[str, bool] = {}
        for name in order:
            steps, gaps, key_loc = parsed[name]
            whole = not gaps
            for number, step in enumerate(steps, 1):
                if step.is_application and step.job in complete and not complete[step.job]:
                    whole = False
                    self.warn(
                        "W702",
                        f"application '{name}' is incomplete: step {number} '{step.job}' is the incomplete application '{step.job}'",
                        step.loc,
                        f"fill the gaps of '{step.job}' first; an incomplete application may be kept but not run",
                    )
            complete[name] = whole
            self.out.applications[name] = ApplicationSpec(name, tuple(steps), key_loc, whole)

    def application_order(self, graph: dict[str, set[str]], locs: dict[str, Location], key_locs: dict[str, Location]) -> list[str]:
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

    def check_step(self, app: str, number: int, item: Any, loc: Location) -> tuple[ApplicationStep, bool] | None:
        """One step and whether it leaves a gap (a job without its object); None if it is wrong."""
        args: Any = None
        args_loc = loc
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
                f"step {number} of application '{app}' must be a job name or {{job: {{object: value}}}}, got: {describe(item)}",
                location_of(item, loc),
                "e.g. - move: {q_d: [0, -0.5, 0.5, 0, 0, 0]}",
            )
            return None
        if job not in self.job_names and job in self.app_names:
            if args is not None:
                self.error(
                    "E709",
                    f"step {number} of application '{app}' gives objects to application '{job}', which takes none",
                    location_of(args, args_loc),
                    f"give the objects to the steps inside application '{job}'",
                )
                return None
            return ApplicationStep(job, {}, loc, is_application=True), False
        if job not in self.job_names:
            self.error("E211", f"step {number} of application '{app}' runs job '{job}', which 'jobs' does not declare", loc,
                       did_you_mean(job, self.job_names | self.app_names, "jobs and applications"))
            return None
        spec = self.out.jobs.get(job)
        if spec is None:
            return None  # the job itself is wrong, and was reported there
        arguments: dict[str, Any] = {}
        if args is not None:
            m = self.mapping(args, args_loc, f"arguments of job '{job}' in application '{app}'", "e.g. move: {q_d: [0, 0, 0]}")
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
            kind = self.var_object.get(str(spec.object), "?")
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
                        f"step {number} of application '{app}' gives '{var}' to job '{job}', but its object is '{spec.object}' (type {kind})",
                        m.key_loc(var),
                        f"write '- {job}: {{{spec.object}: <value>}}'",
                    )
                    return None
                variable = self.out.variables.get(str(var))
                if variable is None:
                    return None  # the job's own object is wrong, and was reported there
                array = self.check_value(val, m.value_loc(var), variable.dtype, variable.shape, f"object '{var}' of step {number} of application '{app}'")
                if array is None:
                    return None
                arguments[str(var)] = plain(val)
        gap = bool(spec.object) and spec.object not in arguments
        if gap:
            self.warn(
                "W701",
                f"application '{app}' is incomplete: step {number} '{job}' needs an object of type {self.var_object.get(str(spec.object), '?')}",
                loc,
                f"give it as '- {job}: {{{spec.object}: <value>}}'; an incomplete application may be kept but not run",
            )
        return ApplicationStep(job, arguments, loc), gap


def _name_offset(text: str, name: str) -> int:
    """Where `name` first appears in `text` as a whole word; 0 if it cannot be found."""
    match = re.search(rf"(?<![A-Za-z0-9_]){re.escape(name)}(?![A-Za-z0-9_])", text)
    return match.start() if match else 0
