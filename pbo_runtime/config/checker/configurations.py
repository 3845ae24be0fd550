"""Configurations and their data flow: which tasks run together, who writes what each task reads,
and what no configuration or no task uses.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pbo_runtime.config.checker.base import CheckerBase
from pbo_runtime.config.checker.model import _Binding, _Task
from pbo_runtime.config.checker.words import _and_list, _ms, describe, did_you_mean
from pbo_runtime.config.model import ConfigurationSpec, Location
from pbo_runtime.config.yaml_nodes import YList, YMap, location_of

_JOIN_HINT = "an output has one writer; join them with a join connector (TR Figure 6)"


class ConfigurationChecks(CheckerBase):
    """Rules for `configurations:`, the data flow in each, and what is left unused."""

    if TYPE_CHECKING:  # rules of other mixins this one calls; the whole checker has them
        def check_device_claims(self, config: str, members: list[_Task]) -> None: ...

    def check_configurations(self, top: YMap) -> None:
        for name, value, key_loc, value_loc in self.entries(
            top, "configurations", "configuration", "e.g. configurations: {joint_pid: [robot, pid]}"
        ):
            self.config_names.add(name)
            if not isinstance(value, YList):
                loc = value_loc
                self.error(
                    "E113",
                    f"configuration '{name}' must be a list of task names, got: {describe(value)}",
                    location_of(value, loc),
                    f"e.g. {name}: [robot, pid]",
                )
                continue
            members: list[tuple[str, Location]] = []
            first: dict[str, Location] = {}
            # A module's instance is the module with the variables its output ports write: two tasks
            # of one module are two instances unless they would write the same ones (E407). A task
            # that writes nothing (a data logger, a link's sending end) repeats nothing.
            instances: dict[tuple[str, frozenset[str]], tuple[str, Location]] = {}
            ok = True
            for i, item in enumerate(value):
                item_loc = value.item_loc(i)
                task = item if isinstance(item, str) else self.text(item, item_loc, f"task of configuration '{name}'")
                if task is None:
                    ok = False
                    continue
                if task not in self.task_names:
                    self.error(
                        "E209",
                        f"configuration '{name}' names task '{task}', which 'tasks' does not declare",
                        item_loc,
                        did_you_mean(task, self.task_names, "declared"),
                    )
                    ok = False
                    continue
                if task in first:
                    self.error(
                        "E402",
                        f"task '{task}' appears twice in configuration '{name}' (first at line "
                        f"{first[task].line}, column {first[task].column})",
                        item_loc,
                        "a task runs at most once in a configuration; to run its module twice, declare a second task",
                        [(first[task], f"task '{task}' is first listed here")],
                    )
                    ok = False
                    continue
                record = self.tasks.get(task)
                module = record.module if record is not None else ""
                writes = frozenset(variable for _, variable in record.outputs) if record is not None else frozenset()
                instance = (module, writes)
                if module and writes and instance in instances:
                    other, _other_loc = instances[instance]
                    assert record is not None
                    relink = ", ".join(f"{port}: {variable}_{task}" for port, variable in record.outputs)
                    declare = _and_list([f"'{variable}_{task}'" for _, variable in record.outputs])
                    self.error(
                        "E407",
                        f"configuration '{name}' runs module '{module}' twice: as task '{other}' (line "
                        f"{self.tasks[other].loc.line}) "
                        f"and as task '{task}' (line {record.loc.line}), both writing {_and_list(sorted(writes))}",
                        item_loc,
                        f"one set of output ports has one writer: give task '{task}' outputs of its own (declare {declare} "
                        f"under variables:, link them with ports: {{{relink}}}) and join each with the other task's by a join "
                        "connector (TR Figure 6), or leave one of the two tasks out of the configuration",
                    )
                    ok = False
                    # still a member: what it writes counts, so no follow-on "nobody writes it" (E403),
                    # and no follow-on "two writers" (E401) with the task it repeats
                    first[task] = item_loc
                    members.append((task, item_loc))
                    self.config_repeats.setdefault(name, set()).add(task)
                    continue
                if module and writes:
                    instances[instance] = (task, item_loc)
                first[task] = item_loc
                members.append((task, item_loc))
            self.config_members[name] = members
            self.config_locs[name] = key_loc
            self.config_list_locs[name] = location_of(value, value_loc)
            if ok:
                self.out.configurations[name] = ConfigurationSpec(name, tuple(t for t, _ in members), key_loc)

    def job_written(self) -> set[str]:
        """Variables job control writes (objects and initial values): the same for every configuration."""
        cached = getattr(self, "_job_written", None)
        if cached is None:
            cached = self._job_written = set(self.var_object) | self.var_initial
        return cached

    def check_data_flow(self, config: str) -> None:
        """Inputs have one writer; no variable two; consts come from init-time writers; exclusive devices."""
        members = [self.tasks[t] for t, _ in self.config_members.get(config, []) if t in self.tasks]
        # A task with an unresolved port may be the missing writer: report no "nobody writes it"
        # errors then, only what the resolved links prove.
        repeats = self.config_repeats.get(config, set())
        complete = all(t.ok for t in members if t.name not in repeats) and len(members) == len(
            self.config_members.get(config, [])
        )
        # A repeated module's task (E407) is not judged again: its writes satisfy readers (no
        # follow-on E403/E405), but are not counted as second writers (E401) or as the kind of
        # write a const needs (E404); its own reads repeat the first task's.
        writers: dict[str, list[tuple[_Task, _Binding]]] = {}
        repeat_written: set[str] = set()
        for task in members:
            for b in task.bindings:
                if not b.port.kind.is_input:
                    if task.name in repeats:
                        repeat_written.add(b.variable)
                    else:
                        writers.setdefault(b.variable, []).append((task, b))
        for var, ws in writers.items():
            if len(ws) > 1:
                detail = _and_list([f"'{t.name}' (line {b.loc.line})" for t, b in ws])
                count = "two" if len(ws) == 2 else str(len(ws))
                self.error(
                    "E401",
                    f"variable '{var}' has {count} writers in configuration '{config}': {detail}",
                    ws[1][1].loc,
                    _JOIN_HINT,
                    [(b.loc, f"task '{t.name}' writes '{var}' (port '{b.port.name}')") for t, b in ws if b is not ws[1][1]],
                )
        job_written = self.job_written()
        member_names = {t.name for t in members}
        left_out: dict[tuple[str, ...], list[tuple[_Task, _Binding]]] = {}  # the tasks that would write them -> their readers
        for task in members:
            if task.name in repeats:
                continue
            for b in task.bindings:
                if not b.port.kind.is_input:
                    continue
                ws = writers.get(b.variable, [])
                given = task.fresh_within.get(b.port.name)
                if ws and given is not None and given[0] <= ws[0][0].period:
                    w_task = ws[0][0]
                    self.error(
                        "E512",
                        f"fresh_within of port '{b.port.name}' of task '{task.name}' ({_ms(given[0])}) is not longer than the "
                        f"period of its writer '{w_task.name}' ({_ms(w_task.period)}) in "
                        f"configuration '{config}': every read would be stale",
                        given[1],
                        f"give at least two periods of '{w_task.name}' ({_ms(2 * w_task.period)}: one missed write tolerated), "
                        "or leave it out for that default",
                    )
                if not ws and b.variable in repeat_written:
                    continue
                if not ws and b.variable not in job_written:
                    if not complete:
                        continue
                    inside = self.combined_inside(b.variable)
                    outside = self.writers_outside(b.variable, member_names)
                    if outside and not inside:  # the fix goes in the configuration's list: reported there (E408)
                        left_out.setdefault(outside, []).append((task, b))
                        continue
                    if inside:  # a member writes it for another member: the fix is the combined task's export:
                        combined = inside[0]
                        hint = (f"'{b.variable}' stays inside combined task '{combined}' (one member writes it for another, "
                                f"never to the table): add it to the task's params, export: [{b.variable}]")
                        if combined not in member_names:
                            hint += f", and add '{combined}' to configuration '{config}'"
                    else:
                        hint = (
                            did_you_mean(b.variable, written, "written")
                            if (written := sorted(set(writers) | job_written))
                            else "nothing is written"
                        ) + f"; add a task that writes '{b.variable}', or give it an initial: value"
                    self.error(
                        "E403",
                        f"task '{task.name}' reads {b.port.kind.value} '{b.variable}', but no "
                        f"task in configuration '{config}' writes it",
                        b.loc,
                        hint,
                        [
                            (self.tasks[c].loc, f"combined task '{c}' writes '{b.variable}' for its own members only")
                            for c in inside
                        ],
                    )
                    continue
                if not b.port.kind.needs_initial_value or b.variable in self.var_initial:
                    continue
                if ws and not any(w.port.kind.supplies_initial_value for _, w in ws):
                    w_task, w_binding = ws[0]
                    self.error(
                        "E404",
                        f"task '{task.name}' reads {b.port.kind.value} '{b.variable}' before "
                        f"its init, but its writer '{w_task.name}' "
                        f"in configuration '{config}' writes it as {w_binding.port.kind.value} (only after each cycle)",
                        b.loc,
                        f"make port '{w_binding.port.name}' of module '{w_task.module}' out-const or out-both, "
                        f"or give variable '{b.variable}' an initial: value",
                        [(w_binding.loc, f"task '{w_task.name}' writes '{b.variable}' as {w_binding.port.kind.value}")],
                    )
                elif not ws and complete:
                    self.error(
                        "E405",
                        f"task '{task.name}' reads {b.port.kind.value} '{b.variable}' before "
                        f"its init, but in configuration '{config}' "
                        "only job control sets it, as a job's object, after tasks are spawned",
                        b.loc,
                        f"give variable '{b.variable}' an initial: value",
                    )
        for outside, readers in left_out.items():
            self.report_left_out(config, outside, readers)
        self.check_device_claims(config, members)

    def combined_inside(self, variable: str) -> list[str]:
        """The combined tasks whose members pass `variable` among themselves without exporting it
        (their params' `local_variables()`): a reader outside needs it in their `export:`."""
        found = []
        for t in self.tasks.values():
            local = getattr(t.built_params, "local_variables", None)
            try:
                if callable(local) and variable in local():
                    found.append(t.name)
            except Exception:  # a module's own helper that fails: no hint from it
                continue
        return found

    def writers_outside(self, variable: str, members: set[str]) -> tuple[str, ...]:
        """The declared tasks, not in `members`, that write `variable`."""
        return tuple(t.name for t in self.tasks.values()
                     if t.name not in members and any(b.variable == variable and not b.port.kind.is_input for b in t.bindings))

    def report_left_out(self, config: str, outside: tuple[str, ...], readers: list[tuple[_Task, _Binding]]) -> None:
        """E408 at the configuration's list: it leaves out the task that writes what its tasks read."""
        variables = list(dict.fromkeys(b.variable for _, b in readers))
        readers_named = _and_list(list(dict.fromkeys(f"'{t.name}'" for t, _ in readers)))
        shown = _and_list([f"'{v}'" for v in variables])
        read: dict[tuple[str, Location], list[str]] = {}  # a reader's link (the task, or its ports: entry) -> what it reads there
        for t, b in readers:
            read.setdefault((t.name, b.loc), []).append(f"{b.port.kind.value} '{b.variable}'")
        notes = [(loc, f"task '{name}' reads {_and_list(what)}") for (name, loc), what in read.items()]
        notes += [(self.tasks[w].loc, f"task '{w}' writes {_and_list([repr(v) for v in variables])}") for w in outside]
        if len(outside) == 1:
            members = [t for t, _ in self.config_members.get(config, [])]
            self.error(
                "E408",
                f"configuration '{config}' leaves out task '{outside[0]}', which writes {shown}, read by {readers_named}",
                self.config_list_locs[config],
                f"add it: {config}: [{', '.join([*members, outside[0]])}]",
                notes,
            )
        else:
            self.error(
                "E408",
                f"configuration '{config}' has no writer of {shown}, read by {readers_named}; "
                f"{_and_list([repr(w) for w in outside])} write {'it' if len(variables) == 1 else 'them'}",
                self.config_list_locs[config],
                f"add one of {', '.join(repr(w) for w in outside)} to configuration '{config}'",
                notes,
            )

    def check_unused(self) -> None:
        in_a_config = {t for members in self.config_members.values() for t, _ in members}
        for task in self.tasks.values():
            if task.name not in in_a_config:
                self.warn(
                    "W201",
                    f"task '{task.name}' is in no configuration",
                    task.loc,
                    "it is spawned but never turned on; add it to a configuration or remove it",
                )
        if any(not t.ok for t in self.tasks.values()):
            return  # who reads what is unknown while a task's ports are unknown
        read = {b.variable for t in self.tasks.values() for b in t.bindings if b.port.kind.is_input}
        for name, loc in self.var_locs.items():
            if name not in read and name not in self.expression_names and name not in self.var_inferred:
                self.warn("W202", f"variable '{name}' is read by no task", loc, "remove it, or link a task's input port to it")
