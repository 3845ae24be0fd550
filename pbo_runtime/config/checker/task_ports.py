"""A task's ports: the ports its module lists, the variable each links to (`ports:`, else the
port's own name), their dtypes and shapes against the variables, and the ports a module groups as one shape.
"""

from __future__ import annotations

from typing import Any

from pbo_runtime.config.checker.base import CheckerBase, named_in
from pbo_runtime.config.checker.model import _Binding, _Link, _Linked, _Task
from pbo_runtime.config.checker.words import _show_shape, did_you_mean
from pbo_runtime.config.model import Location
from pbo_runtime.config.yaml_nodes import YMap
from pbo_runtime.objects.module import PortBasedObject
from pbo_runtime.objects.ports import ANY_DTYPE, PortSpec


class TaskPortChecks(CheckerBase):
    """Rules for the ports of `tasks:` and the variables they link (E205/E206, E212, E301-E307, E319)."""

    _mislinked: set[str]  # the variables some port disagrees with, for report_link_mismatches (set by check_tasks)

    def module_ports(self, task: _Task, module_class: Any, spec: YMap) -> tuple[PortSpec, ...] | None:
        # A module whose ports do not depend on its params (most) lists the same ports for every
        # task: asked once per check, not once per task.
        fixed = self._fixed_ports.get(module_class)
        if fixed is not None:
            return fixed
        try:
            # ports may depend on params (a data logger's inputs); without valid params, the class's
            built = getattr(task, "built_params", None)
            ports = tuple(module_class.ports_for(built) if built is not None else module_class.ports())
        except Exception as exc:  # the module is broken, not the YAML; say so
            self.error(
                "E307", f"module '{task.module}' of task '{task.name}' cannot list its ports: {exc!r}", spec.value_loc("module")
            )
            return None
        if not _ports_from_params(module_class):
            self._fixed_ports[module_class] = ports
        return ports

    def port_shape(self, port: PortSpec, variable_shape: tuple[int, ...]) -> tuple[int, ...]:
        """`port.resolved_shape` with this file's dims; a declared shape is resolved once, not per task.

        Raises what `resolved_shape` raises (a shape that fails is never remembered).
        """
        declared = port.shape
        try:
            shape = self._port_shapes.get(declared) if declared is not None else None
        except TypeError:  # an unhashable declared shape: resolved afresh each time
            shape = declared = None
        if shape is None:
            while True:
                try:
                    shape = port.resolved_shape(self.out.dims, variable_shape)
                    break
                except KeyError as exc:  # a dim 'dims:' leaves out may be the plant's robot's (NDOF)
                    if not isinstance(exc.args[0], str) or self.robot_dim(exc.args[0]) is None:
                        raise
            if declared is not None:
                self._port_shapes[declared] = shape
        return shape

    def task_links(self, task: _Task, spec: YMap, module_class: Any) -> tuple[list[_Link], bool] | None:
        """Each port of the task and the variable it links to (`ports:`, else the port's own name),
        and whether `ports:` was right; None when the module cannot list its ports."""
        name = task.name
        ports = self.module_ports(task, module_class, spec)
        if ports is None:
            return None
        declared = {p.name: p for p in ports}
        relinked: dict[str, tuple[str, Location]] = {}
        ok = True
        if "ports" in spec and spec["ports"] is not None:
            m = self.mapping(spec["ports"], spec.value_loc("ports"), f"ports of task '{name}'", "e.g. ports: {tau: tau_u}")
            if m is None:
                ok = False
            else:
                for port_name, var in m.items():
                    if port_name not in declared:
                        self.error(
                            "E212",
                            f"module '{task.module}' of task '{name}' has no port '{port_name}'",
                            m.key_loc(port_name),
                            did_you_mean(port_name, declared, "ports"),
                        )
                        ok = False
                        continue
                    var_loc = m.value_loc(port_name)
                    var_name = (
                        var
                        if isinstance(var, str)
                        else self.text(var, var_loc, f"variable of port '{port_name}' of task '{name}'")
                    )
                    if var_name is None:
                        ok = False
                        continue
                    relinked[port_name] = (var_name, var_loc)
        links = []
        for port in ports:
            link = relinked.get(port.name)
            if link is None:
                links.append(_Link(port, port.variable, task.loc, False))
            else:
                links.append(_Link(port, link[0], link[1], True))
        return links, ok

    def bind_task_ports(self, task: _Task, links: list[_Link], ok: bool) -> bool:
        """Each link checked against its variable (declared, or inferred from the ports): dtype and shape."""
        name = task.name
        var_locs, var_ok, variables = self.var_locs, self.var_ok, self.out.variables
        for link in links:
            port, var, loc, explicit = link.port, link.variable, link.loc, link.explicit
            if var not in var_locs:
                if var in self.infer_failed:
                    ok = False  # its ports disagree, and each was reported
                    continue
                if port.shape is not None and not self.port_shape_resolves(task, port, loc):
                    ok = False
                    continue
                why = self.infer_failed_why.get(var)
                if explicit:
                    self.error(
                        "E205",
                        f"task '{name}' links port '{port.name}' to variable '{var}', which 'variables' does not declare",
                        loc,
                        (f"{why}; declare it under variables:" if why else
                         f"{did_you_mean(var, self.var_locs, 'declared')}; a new variable that only one task's ports: "
                         f"names needs an entry under variables: (so that a typo never makes one)"),
                    )
                else:
                    self.error(
                        "E206",
                        f"task '{name}' (module '{task.module}') links port '{port.name}' by default to variable '{var}', "
                        "which 'variables' does not declare and its ports cannot define",
                        loc,
                        f"{why}; declare '{var}' under variables: (e.g. {var}: {{type: float64, shape: [NDOF]}}), "
                        f"or link the port with ports: {{{port.name}: <variable>}}",
                    )
                ok = False
                continue
            if var not in var_ok:
                ok = False  # the variable itself is wrong and was reported
                continue
            variable = variables[var]
            own_dtype, own_shape = port.dtype != ANY_DTYPE, port.shape is not None
            if port.dtype == ANY_DTYPE:  # a port that takes whatever its variable is
                port = PortSpec(port.name, port.kind, port.variable, variable.dtype,
                                variable.shape if port.shape is None else port.shape, port.doc)
            try:
                shape = self.port_shape(port, variable.shape)
            except KeyError as exc:
                self.report_unknown_port_dim(task, port, loc, exc)
                ok = False
                continue
            except (TypeError, ValueError) as exc:
                self.error("E306", f"port '{port.name}' of module '{task.module}' has a bad shape {port.shape!r}: {exc}", loc)
                ok = False
                continue
            # A mismatch is reported once every task is linked (`report_link_mismatches`): where all the
            # ports of a variable agree with each other, it is the declaration that is wrong.
            self.var_links.setdefault(var, []).append(_Linked(task.name, port, shape, loc, own_dtype, own_shape))
            if port.dtype != variable.dtype or shape != variable.shape:
                self._mislinked.add(var)
                ok = False
                continue
            task.bindings.append(_Binding(port, var, shape, loc))
        return ok

    def report_link_mismatches(self) -> None:
        """E301/E302 for the ports whose dtype or shape differs from their variable's. When every port
        that links a variable agrees (on the dtype, or on the shape), the declaration is what is
        wrong: one error at its type: (or shape:), the ports as notes. Otherwise one at each odd port."""
        mislinked = self._mislinked  # a variable every port agrees with has nothing to report
        for var, every in self.var_links.items():
            if var not in mislinked:
                continue
            variable = self.out.variables[var]
            wrong_type = [link for link in every if link.port.dtype != variable.dtype]
            links = [link for link in every if link.own_dtype]  # a port of any dtype agrees with every variable
            if wrong_type:
                dtypes = {link.port.dtype for link in links}
                if len(dtypes) == 1:
                    dtype = dtypes.pop()
                    self.error(
                        "E301",
                        f"variable '{var}' is {variable.dtype}, but {_ports_that_link(links)} {dtype}",
                        self.declared_at(var, "type"),
                        f"change the type of '{var}' to {dtype}",
                        [
                            (
                                link.loc,
                                f"task '{link.task}' port '{link.port.name}' ({link.port.kind.value}) is {link.port.dtype}",
                            )
                            for link in links
                        ],
                    )
                    continue
                for link in wrong_type:
                    self.error(
                        "E301",
                        f"task '{link.task}' port '{link.port.name}' ({link.port.kind.value}) is {link.port.dtype}, "
                        f"but variable '{var}' is {variable.dtype}",
                        link.loc,
                        f"link the port to a {link.port.dtype} variable",
                        [(self.declared_at(var, "type"), f"variable '{var}' is declared {variable.dtype} here")],
                    )
            typed = [link for link in every if link.port.dtype == variable.dtype and link.own_shape]
            wrong_shape = [link for link in typed if link.shape != variable.shape]
            if not wrong_shape:
                continue
            shapes = {link.shape for link in typed}
            if len(shapes) == 1 and not wrong_type:
                shape = shapes.pop()
                written = next(
                    (link.port.shape for link in typed if link.port.shape is not None and link.port.shape != shape), shape
                )
                self.error(
                    "E302",
                    f"variable '{var}' has shape {_show_shape(variable.shape)}, but {_ports_that_link(typed)} "
                    f"of shape {_show_shape(shape)}",
                    self.declared_at(var, "shape"),
                    f"change the shape of '{var}' to [{', '.join(str(d) for d in written)}]",
                    [
                        (
                            link.loc,
                            f"task '{link.task}' port '{link.port.name}' ({link.port.kind.value}) has shape "
                            f"{_show_shape(link.shape)}"
                            + ("" if link.shape == link.port.shape else f" = {_show_shape(link.port.shape)}"),
                        )
                        for link in typed
                    ],
                )
                continue
            for link in wrong_shape:
                named = "" if link.shape == link.port.shape else f" = {_show_shape(link.port.shape)}"
                self.error(
                    "E302",
                    f"task '{link.task}' port '{link.port.name}' ({link.port.kind.value}) has shape "
                    f"{_show_shape(link.shape)}{named}, "
                    f"but variable '{var}' has shape {_show_shape(variable.shape)}",
                    link.loc,
                    f"link the port to a variable of shape {_show_shape(link.shape)}",
                    [
                        (
                            self.declared_at(var, "shape"),
                            f"variable '{var}' is declared with shape {_show_shape(variable.shape)} here",
                        )
                    ],
                )

    def declared_at(self, var: str, key: str) -> Location:
        """Where a variable's entry gives `key` (type, shape), else where the entry is."""
        node = self.var_nodes.get(var)
        if node is not None and key in node:
            return node.value_loc(key)
        return self.var_locs.get(var, self.out.variables[var].loc)

    def check_same_shapes(self, task: _Task, spec: YMap, module_class: Any) -> bool:
        """E319: the ports a module groups as one shape (`same_shape`: a join's output and inputs) link
        variables of one shape. Reported where the odd port is named (a join's `inputs:` item), with
        the variable's declaration and the port it disagrees with as notes."""
        try:
            groups = tuple(module_class.same_shape(task.built_params)) if task.built_params is not None else ()
        except Exception as exc:  # the module is broken, not the YAML
            self.error("E307", f"module '{task.module}' of task '{task.name}' cannot say which ports share a shape: {exc!r}",
                       spec.value_loc("module"))
            return False
        bound = {b.port.name: b for b in task.bindings}
        ok = True
        for group in groups:
            members = [bound[port] for port in group if port in bound]
            shapes = [b.shape for b in members]
            if len(set(shapes)) < 2:
                continue
            # the shape most of them have is the one meant (the first port's on a tie: a join's output)
            meant = max(shapes, key=lambda shape: (shapes.count(shape), -shapes.index(shape)))
            reference = next(b for b in members if b.shape == meant)
            for b in members:
                if b.shape == meant:
                    continue
                ok = False
                where = named_in(spec.get("params"), b.port.name) or b.loc
                notes = [
                    (
                        reference.loc,
                        f"port '{reference.port.name}' links variable '{reference.variable}', of shape {_show_shape(meant)}",
                    )
                ]
                if b.variable in self.var_locs:
                    notes.append(
                        (
                            self.var_locs[b.variable],
                            f"variable '{b.variable}' is declared here, with shape {_show_shape(b.shape)}",
                        )
                    )
                self.error(
                    "E319",
                    f"task '{task.name}' (module '{task.module}') needs one shape on ports {', '.join(repr(p) for p in group)}: "
                    f"port '{b.port.name}' links variable '{b.variable}', of shape {_show_shape(b.shape)}, "
                    f"where port '{reference.port.name}' links '{reference.variable}', of shape {_show_shape(meant)}",
                    where,
                    f"link port '{b.port.name}' to a variable of shape "
                    f"{_show_shape(meant)}, or change the shape of '{b.variable}'",
                    notes,
                )
        return ok

    def port_shape_resolves(self, task: _Task, port: PortSpec, loc: Location) -> bool:
        """True if the port's declared shape resolves with the dims; else E304 or E306, reported here."""
        try:
            self.port_shape(port, ())
        except KeyError as exc:
            self.report_unknown_port_dim(task, port, loc, exc)
            return False
        except (TypeError, ValueError) as exc:
            self.error("E306", f"port '{port.name}' of module '{task.module}' has a bad shape {port.shape!r}: {exc}", loc)
            return False
        return True

    def report_unknown_port_dim(self, task: _Task, port: PortSpec, loc: Location, exc: KeyError) -> None:
        self.error(
            "E304",
            f"port '{port.name}' of module '{task.module}' (task '{task.name}') has shape {_show_shape(port.shape)} "
            f"with dim {exc}, which 'dims' does not define",
            loc,
            did_you_mean(str(exc.args[0]), self.out.dims, "defined")
            + (
                ""
                if self.out.plant is not None
                else "; or add a plant: whose robot gives it (e.g. plant: {model: puma560} gives NDOF)"
            ),
        )


def _ports_from_params(module_class: Any) -> bool:
    """Whether a module's ports depend on its params (it overrides `ports_for`)."""
    own = getattr(getattr(module_class, "ports_for", None), "__func__", None)
    return own is not None and own is not PortBasedObject.ports_for.__func__  # type: ignore[attr-defined]


def _ports_that_link(links: list[_Linked]) -> str:
    """'the port that links it is' / 'all 3 ports that link it are' (the dtype or shape follows)."""
    if len(links) == 1:
        return "the one port that links it is"
    return f"all {len(links)} ports that link it are"
