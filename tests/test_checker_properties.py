"""Property test of the checker's data-flow rules (E401, E403-E408) against an oracle.

Hypothesis draws small random task sets, legal and illegal: variables from a fixed pool (some
left undeclared, some with `initial:` or `object:`), tasks of six fake modules whose ports are
relinked at random (now and then to an undeclared or wrongly shaped variable, or the module is
not registered at all), and configurations that are subsets of the tasks. The oracle below works
out, from that data alone, which data-flow errors docs/configuration.md ("The rules") and
docs/error-codes.md (E4xx) call for, and the test checks that the checker reports exactly those;
a set with no violation must check clean, with an init order that starts every const's
producer before its readers.
"""

from __future__ import annotations

import itertools
import re
import tempfile
from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pbo_runtime import InBoth, InConst, InVar, ModuleError, OutBoth, OutConst, OutVar, PortBasedObject
from pbo_runtime.config.loader import CheckResult, check_file

# --- the pool: variables, and fake modules declared as data ---------------------------------

SCALARS = ("a", "b", "c", "d", "e")
VECTORS = ("u", "v", "w")  # shape [N], N = 3
POOL = SCALARS + VECTORS
GHOST = "ghost"  # never declared: made from its ports when they agree, else a link to it leaves a task unresolved (E205, E317)

# module -> its ports as (port name, kind, default variable); the vector-ness follows the variable.
MODULE_PORTS: dict[str, tuple[tuple[str, str, str], ...]] = {
    "m_source": (("k", "out-const", "a"), ("y", "out-var", "u")),
    "m_filter": (("k", "in-const", "a"), ("x", "in-var", "u"), ("y", "out-var", "v")),
    "m_both": (("x", "in-both", "b"), ("y", "out-both", "c")),
    "m_mixer": (("x", "in-var", "c"), ("k", "in-const", "b"), ("y", "out-const", "d")),
    "m_sink": (("x", "in-var", "v"), ("k", "in-both", "d"), ("y", "out-var", "e")),
    "m_vector": (("k", "in-const", "e"), ("y", "out-both", "w"), ("x", "in-var", "w")),
}
UNREGISTERED = "m_missing"

INPUTS = frozenset({"in-const", "in-var", "in-both"})
NEEDS_INIT = frozenset({"in-const", "in-both"})  # read before init
SUPPLIES_INIT = frozenset({"out-const", "out-both"})  # written after init
_PORT_CLASS = {"in-const": InConst, "out-const": OutConst, "in-var": InVar, "out-var": OutVar,
               "in-both": InBoth, "out-both": OutBoth}


def _shape(var: str) -> tuple[str, ...]:
    return ("N",) if var in VECTORS else ()


def _module_class(name: str) -> type:
    attrs = {port: _PORT_CLASS[kind](var, shape=_shape(var)) for port, kind, var in MODULE_PORTS[name]}
    return type("".join(part.title() for part in name.split("_")), (PortBasedObject,), attrs)


MODULES: dict[str, type] = {name: _module_class(name) for name in MODULE_PORTS}


def lookup(name: str) -> type:
    if name not in MODULES:
        raise ModuleError(f"no module named '{name}'")
    return MODULES[name]


# --- a generated task set ---------------------------------------------------------------------


@dataclass(frozen=True)
class Variable:
    name: str
    initial: bool
    object: bool


@dataclass(frozen=True)
class Task:
    name: str
    module: str
    rtpu: str
    period: str
    links: tuple[tuple[str, str], ...]  # every port -> its variable (the default one or not)


@dataclass(frozen=True)
class TaskSet:
    variables: tuple[Variable, ...]
    tasks: tuple[Task, ...]
    configurations: tuple[tuple[str, tuple[str, ...]], ...]

    def to_yaml(self) -> str:
        variables: dict[str, dict[str, object]] = {}
        for v in self.variables:
            entry: dict[str, object] = {"type": "float64"}
            if _shape(v.name):
                entry["shape"] = list(_shape(v.name))
            if v.object:
                entry["object"] = f"{v.name}_value"
            if v.initial:
                entry["initial"] = 0
            variables[v.name] = entry
        tasks: dict[str, dict[str, object]] = {}
        for t in self.tasks:
            entry = {"module": t.module, "rtpu": t.rtpu, "period": t.period}
            defaults = {port: var for port, _, var in MODULE_PORTS.get(t.module, ())}
            relinked = {port: var for port, var in t.links if defaults.get(port) != var}
            if relinked:
                entry["ports"] = relinked
            tasks[t.name] = entry
        doc = {
            "subsystem": "prop",
            "rtpus": ["rtpu0", "rtpu1"],
            "dims": {"N": 3},
            "variables": variables,
            "tasks": tasks,
            "configurations": {name: list(members) for name, members in self.configurations},
        }
        return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=200)


def _weighted(true_weight: int, false_weight: int) -> st.SearchStrategy[bool]:
    return st.sampled_from([False] * false_weight + [True] * true_weight)


@st.composite
def task_sets(draw: st.DrawFn) -> TaskSet:
    # "wild" leaves variables undeclared, links ports to undeclared or wrongly shaped variables and
    # names an unregistered module; "tidy" declares the whole pool and links every port soundly;
    # "distinct" also gives each task its own module and seldom relinks a port, so legal sets with
    # const producers and readers (an init order to check) come up often.
    mode = draw(st.sampled_from(["distinct", "tidy", "wild"]))
    p_initial = draw(st.sampled_from([1, 4, 8]))  # out of 10
    variables = []
    for name in POOL:
        if mode != "wild" or draw(_weighted(9, 1)):
            initial = draw(_weighted(p_initial, 10 - p_initial))
            obj = draw(_weighted(2, 8))
            variables.append(Variable(name, initial, obj))
    modules = list(MODULE_PORTS)
    if mode == "distinct":
        chosen = draw(st.permutations(modules))[: draw(st.integers(1, len(modules)))]
    else:
        pool = modules + ([UNREGISTERED] if mode == "wild" else [])
        chosen = draw(st.lists(st.sampled_from(pool), min_size=1, max_size=8))
    choices = {
        "distinct": ["default"] * 6 + ["relink"],
        "tidy": ["default"] * 3 + ["relink"] * 3,
        "wild": ["default"] * 3 + ["relink"] * 3 + ["ghost", "wrong shape"],
    }[mode]
    tasks = []
    for i, module in enumerate(chosen):
        links = []
        for port, _, default in MODULE_PORTS.get(module, ()):
            same, other = (VECTORS, SCALARS) if default in VECTORS else (SCALARS, VECTORS)
            choice = draw(st.sampled_from(choices))
            if choice == "relink":
                var = draw(st.sampled_from(same))
            elif choice == "wrong shape":
                var = draw(st.sampled_from(other))
            else:
                var = GHOST if choice == "ghost" else default
            links.append((port, var))
        rtpu = draw(st.sampled_from(["rtpu0", "rtpu1"]))
        period = draw(st.sampled_from(["1 ms", "2 ms", "5 ms"]))
        tasks.append(Task(f"t{i}", module, rtpu, period, tuple(links)))
    names = [t.name for t in tasks]
    configurations = []
    for j in range(draw(st.integers(1, 3))):
        members = draw(st.lists(st.sampled_from(names), min_size=1, max_size=len(names), unique=True))
        configurations.append((f"c{j}", tuple(members)))
    return TaskSet(tuple(variables), tuple(tasks), tuple(configurations))


# --- the oracle -------------------------------------------------------------------------------

# Known checker bug (see test_a_task_left_out_for_e407_still_counts_as_a_writer below): a task
# reported by E407 is left out of the data flow, so what only it writes is reported as written
# by nobody (E403, or E405). Set this to False once the checker counts its writes.
CHECKER_DROPS_E407_WRITERS = False

Key = tuple[str, str | None, object]


@dataclass
class Verdict:
    errors: Counter[Key]
    resolved: dict[str, bool]  # task -> all its ports link to declared variables of their shape
    edges: set[tuple[str, str]]  # (producer, reader) of a const, across all resolved tasks
    cycle: bool


def bindings(task: Task, shapes: dict[str, tuple[str, ...]]) -> list[tuple[str, str]]:
    """(kind, variable) of each port that links to a known variable (declared or inferred) of the port's shape."""
    kinds = {port: (kind, default) for port, kind, default in MODULE_PORTS.get(task.module, ())}
    out = []
    for port, var in task.links:
        kind, default = kinds[port]
        if var in shapes and shapes[var] == _shape(default):
            out.append((kind, var))
    return out


def inferred(ts: TaskSet, declared: set[str]) -> dict[str, tuple[str, ...]]:
    """The undeclared variables the checker makes from their ports, with their shapes: those linked by
    default or by two ports or more, whose ports agree on the shape (the dtype is float64 for all)."""
    uses: dict[str, list[tuple[tuple[str, ...], bool]]] = defaultdict(list)  # var -> (port's shape, explicit)
    for task in ts.tasks:
        defaults = {port: default for port, _, default in MODULE_PORTS.get(task.module, ())}
        for port, var in task.links:
            if var not in declared:
                uses[var].append((_shape(defaults[port]), var != defaults[port]))
    made = {}
    for var, found in uses.items():
        shapes = {shape for shape, _ in found}
        if not (len(found) == 1 and found[0][1]) and len(shapes) == 1:
            made[var] = shapes.pop()
    return made


def instance_writes(task: Task) -> frozenset[str]:
    kinds = {port: kind for port, kind, _ in MODULE_PORTS.get(task.module, ())}
    return frozenset(var for port, var in task.links if kinds[port] not in INPUTS)


def oracle(ts: TaskSet) -> Verdict:
    declared = {v.name for v in ts.variables}
    initial = {v.name for v in ts.variables if v.initial}
    by_job_control = initial | {v.name for v in ts.variables if v.object}
    tasks = {t.name: t for t in ts.tasks}
    shapes = {name: _shape(name) for name in declared} | inferred(ts, declared)
    bound = {t.name: bindings(t, shapes) for t in ts.tasks}
    resolved = {t.name: t.module in MODULE_PORTS and len(bound[t.name]) == len(t.links) for t in ts.tasks}
    # a module's instance: the module with the variables its outputs link to, resolved or not (issue 22)
    writes = {t.name: instance_writes(t) for t in ts.tasks}
    errors: Counter[Key] = Counter()

    for config, members in ts.configurations:
        running: list[str] = []  # the tasks the rules see; a second instance of a module is E407
        left_out: list[str] = []
        for name in members:
            if writes[name] and any(tasks[other].module == tasks[name].module and writes[other] == writes[name]
                                    for other in running):
                errors["E407", config, name] += 1
                left_out.append(name)
            else:
                running.append(name)
        # what each task writes: per variable, the kinds of the outputs that write it
        written: dict[str, list[str]] = defaultdict(list)
        for name in running:
            for kind, var in bound[name]:
                if kind not in INPUTS:
                    written[var].append(kind)
        written_by_any = set(written)
        if not CHECKER_DROPS_E407_WRITERS:
            written_by_any |= {var for name in left_out for kind, var in bound[name] if kind not in INPUTS}
        for var, kinds in written.items():
            if len(kinds) > 1:
                errors["E401", config, var] += 1
        # an unresolved port may be the missing writer: "nobody writes it" cannot be said then
        all_known = all(resolved[name] for name in running)
        for name in running:
            for kind, var in bound[name]:
                if kind not in INPUTS:
                    continue
                if var not in written_by_any and var not in by_job_control:
                    if all_known and any(kind not in INPUTS for other in tasks if other not in members for kind, v in bound[other]
                                         if v == var):
                        errors["E408", config, var] = 1  # a task the configuration leaves out writes it: said once, at its list
                    elif all_known:
                        errors["E403", config, (name, var)] += 1
                elif kind in NEEDS_INIT and var not in initial:
                    if written.get(var) and not SUPPLIES_INIT & set(written[var]):
                        errors["E404", config, (name, var)] += 1  # every writer writes it after cycles only
                    elif var not in written_by_any and all_known:
                        errors["E405", config, (name, var)] += 1  # only a job's object sets it

    # Every task is spawned, in one init order, whatever configuration it is in.
    producers: dict[str, set[str]] = defaultdict(set)
    for name, ok in resolved.items():
        if ok:
            for kind, var in bound[name]:
                if kind in SUPPLIES_INIT:
                    producers[var].add(name)
    edges = {
        (producer, name)
        for name, ok in resolved.items() if ok
        for kind, var in bound[name] if kind in NEEDS_INIT
        for producer in producers[var]
    }
    cycle = _has_cycle(edges)
    if cycle:
        errors["E406", None, None] += 1
    return Verdict(errors, resolved, edges, cycle)


def _has_cycle(edges: set[tuple[str, str]]) -> bool:
    """Depth-first search for a back edge (a self-loop counts)."""
    after: dict[str, list[str]] = defaultdict(list)
    for a, b in edges:
        after[a].append(b)
    state: dict[str, int] = {}  # 1 on the stack, 2 finished

    def visit(node: str) -> bool:
        state[node] = 1
        for nxt in after[node]:
            if state.get(nxt) == 1 or (nxt not in state and visit(nxt)):
                return True
        state[node] = 2
        return False

    return any(node not in state and visit(node) for node in list(after))


# --- what the checker said, in the oracle's terms ---------------------------------------------

_SUBJECT = {
    "E401": re.compile(r"^variable '(?P<var>\w+)' has \w+ writers in configuration '(?P<config>\w+)'"),
    "E403": re.compile(r"^task '(?P<task>\w+)' reads [\w-]+ '(?P<var>\w+)', but no task in configuration '(?P<config>\w+)'"),
    "E404": re.compile(r"^task '(?P<task>\w+)' reads [\w-]+ '(?P<var>\w+)' before its init, "
                       r"but its writer '\w+' in configuration '(?P<config>\w+)'"),
    "E405": re.compile(r"^task '(?P<task>\w+)' reads [\w-]+ '(?P<var>\w+)' before its init, "
                       r"but in configuration '(?P<config>\w+)' only job control"),
    "E407": re.compile(r"^configuration '(?P<config>\w+)' runs module '\w+' twice: "
                       r"as task '\w+' \(line \d+\) and as task '(?P<task>\w+)'"),
    "E406": re.compile(r"^const dependencies form a cycle: (?P<cycle>\w+( -> \w+)+)$"),
    "E408": re.compile(r"^configuration '(?P<config>\w+)' (leaves out task '\w+', which writes|has no writer of) "
                       r"(?P<vars>.*?), read by "),
}
_UNRESOLVED = re.compile(r"^task '(?P<task>\w+)' (links port|\(module|port '\w+' \(|uses module)")
_UNRESOLVED_CODES = ("E205", "E206", "E301", "E302", "E207", "E317")


def reported(result: CheckResult) -> tuple[Counter[Key], list[list[str]]]:
    found: Counter[Key] = Counter()
    cycles = []
    for error in result.errors:
        pattern = _SUBJECT.get(error.code)
        if pattern is None:
            continue
        match = pattern.match(error.message)
        assert match, f"unexpected {error.code} message: {error.message}"
        parts = match.groupdict()
        if error.code == "E406":
            cycles.append(parts["cycle"].split(" -> "))
            found["E406", None, None] += 1
        elif error.code == "E401":
            found["E401", parts["config"], parts["var"]] += 1
        elif error.code == "E407":
            found["E407", parts["config"], parts["task"]] += 1
        elif error.code == "E408":
            for var in re.findall(r"'(\w+)'", parts["vars"]):
                found["E408", parts["config"], var] += 1
        else:
            found[error.code, parts["config"], (parts["task"], parts["var"])] += 1
    return found, cycles


_DIR = tempfile.TemporaryDirectory(prefix="pbo-checker-properties-")  # @given does not mix with tmp_path
_COUNTER = itertools.count()


def check_text(text: str) -> CheckResult:
    path = Path(_DIR.name) / f"set{next(_COUNTER)}.yaml"
    path.write_text(text)
    return check_file(path, lookup, module_names=lambda: MODULES)


# --- the properties ---------------------------------------------------------------------------


# 300 examples (~2 s): at 150 the fixed seed never draws a task left out for E407 that is the
# only writer of an input, so flipping CHECKER_DROPS_E407_WRITERS would go unnoticed.
@settings(max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(task_sets())
def test_the_checker_reports_exactly_the_data_flow_errors_the_rules_call_for(ts: TaskSet) -> None:
    text = ts.to_yaml()
    result = check_text(text)
    verdict = oracle(ts)
    found, cycles = reported(result)
    assert found == verdict.errors, f"checker {dict(found)} != oracle {dict(verdict.errors)} for\n{text}"

    unresolved = set()
    for error in result.errors:
        if error.code in ("E301", "E302") and error.message.startswith("variable '"):
            # the declaration is wrong, and every port that links it is a note: those tasks are unresolved
            unresolved |= {re.match(r"^task '(\w+)'", note.message)[1] for note in error.notes}  # type: ignore[index]
            continue
        if error.code in _UNRESOLVED_CODES:
            match = _UNRESOLVED.match(error.message)
            assert match, f"unexpected {error.code} message: {error.message}"
            unresolved.add(match["task"])
    assert unresolved == {name for name, ok in verdict.resolved.items() if not ok}, text

    for cycle in cycles:  # the printed cycle is one: each task writes a const the next one reads
        assert cycle[0] == cycle[-1], cycle
        assert all(link in verdict.edges for link in itertools.pairwise(cycle)), (cycle, verdict.edges, text)

    if not verdict.errors and all(verdict.resolved.values()):
        assert result.errors == [], "\n".join(e.format() for e in result.errors) + "\n" + text
        assert result.subsystem is not None
        order = result.subsystem.init_order
        assert sorted(order) == sorted(t.name for t in ts.tasks)
        for producer, reader in verdict.edges:
            assert order.index(producer) < order.index(reader), (producer, reader, order, text)


# --- instances of one module (issue 22), kept as minimal examples -------------------------------

TWO_INSTANCES = """\
subsystem: prop
rtpus: [rtpu0]
dims: {N: 3}
variables:
  a: {type: float64}
  b: {type: float64}
  u: {type: float64, shape: [N]}
  v: {type: float64, shape: [N]}
  d: {type: float64, initial: 0}
  e: {type: float64}
tasks:
  s1: {module: m_source, rtpu: rtpu0, period: 1 ms}
  s2: {module: m_source, rtpu: rtpu0, period: 1 ms, ports: {k: b, y: v}}
  r:  {module: m_sink, rtpu: rtpu0, period: 1 ms}
configurations:
  c: [s1, s2, r]
"""


def test_two_tasks_of_one_module_writing_variables_of_their_own_are_two_instances_issue_22() -> None:
    result = check_text(TWO_INSTANCES)
    assert result.errors == [], "\n".join(e.format() for e in result.errors)


def test_a_second_instance_writing_the_same_variables_is_one_e407_and_nothing_else() -> None:
    result = check_text(TWO_INSTANCES.replace("  s2: {module: m_source, rtpu: rtpu0, period: 1 ms, ports: {k: b, y: v}}\n",
                                              "  s2: {module: m_source, rtpu: rtpu0, period: 1 ms}\n"
                                              "  s3: {module: m_filter, rtpu: rtpu0, period: 1 ms}\n")
                        .replace("[s1, s2, r]", "[s1, s2, s3, r]"))
    assert [e.code for e in result.errors] == ["E407"], "\n".join(e.format() for e in result.errors)
