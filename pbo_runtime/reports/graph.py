"""Draw a configuration as a block diagram, like the figures of the paper (TR Figures 8 and 10).

Tasks are boxes grouped by the RTPU that hosts them; an arrow runs from the task that writes a
variable to each task of the configuration that reads it, labelled with the variable. Links
that carry a value only at init (out-const or in-const ends) are dashed; variables that job
control writes (`object:` or `initial:`, and no writer in the configuration) come from a small
"job control" node; devices are drawn as their own nodes, dotted to the tasks that use them.

`to_dot` gives Graphviz text; `draw` writes `.dot`, or draws `.png`/`.svg` with matplotlib
and a layered left-to-right layout computed here (no Graphviz needed).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pbo_runtime.config.model import Subsystem

JOB_CONTROL = "job control"
SUFFIXES = (".dot", ".png", ".svg")


@dataclass(frozen=True)
class Link:
    """One variable from its writer (a task, or JOB_CONTROL) to one reader."""

    source: str
    target: str
    variable: str
    const: bool  # carried only at init (an out-const or in-const end)
    job: bool = False  # written by job control


@dataclass
class Diagram:
    """What a configuration's block diagram shows, before any layout."""

    subsystem: str
    configuration: str
    tasks: list[str]
    modules: dict[str, str]
    rtpus: dict[str, list[str]]  # RTPU -> its tasks in this configuration, RTPUs in declared order
    links: list[Link]
    devices: dict[str, str]  # device -> driver, for devices the tasks use
    uses: list[tuple[str, str]] = field(default_factory=list)  # (device, task)

    @property
    def has_job_control(self) -> bool:
        return any(link.job for link in self.links)


def diagram(subsystem: Subsystem, configuration: str | None = None) -> Diagram:
    """The nodes and links of a configuration (the first one when not named)."""
    name = _configuration_name(subsystem, configuration)
    tasks = list(subsystem.configurations[name].tasks)
    writers: dict[str, tuple[str, Any]] = {}
    for task in tasks:
        for binding in subsystem.tasks[task].bindings:
            if not binding.port.kind.is_input:
                writers[binding.variable] = (task, binding.port.kind)
    links: list[Link] = []
    for task in tasks:
        for binding in subsystem.tasks[task].bindings:
            kind = binding.port.kind
            if not kind.is_input:
                continue
            writer = writers.get(binding.variable)
            if writer is not None:
                source, out_kind = writer
                links.append(Link(source, task, binding.variable, not (out_kind.every_cycle and kind.every_cycle)))
                continue
            variable = subsystem.variables.get(binding.variable)
            if variable is not None and (variable.object is not None or variable.initial is not None):
                links.append(Link(JOB_CONTROL, task, binding.variable, not kind.every_cycle, job=True))
    rtpus: dict[str, list[str]] = {}
    for rtpu in subsystem.rtpus:
        members = [t for t in tasks if subsystem.tasks[t].rtpu == rtpu.name]
        if members:
            rtpus[rtpu.name] = members
    devices: dict[str, str] = {}
    uses: list[tuple[str, str]] = []
    for task in tasks:
        for device in subsystem.tasks[task].resources:
            spec = subsystem.devices.get(device)
            devices.setdefault(device, spec.driver if spec is not None else "?")
            uses.append((device, task))
    modules = {t: subsystem.tasks[t].module for t in tasks}
    return Diagram(subsystem.name, name, tasks, modules, rtpus, links, devices, uses)


def _configuration_name(subsystem: Subsystem, configuration: str | None) -> str:
    names = list(subsystem.configurations)
    if configuration is None:
        if not names:
            raise ValueError(f"subsystem '{subsystem.name}' has no configuration to draw")
        return names[0]
    if configuration not in subsystem.configurations:
        raise ValueError(f"no configuration named '{configuration}' (configurations: {', '.join(names) or 'none'})")
    return configuration


# --- Graphviz text ----------------------------------------------------------------------------


def _q(text: str) -> str:
    """A DOT string literal; a newline in the text becomes DOT's line break."""
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'


def _device_id(device: str) -> str:
    return f"device:{device}"


def to_dot(subsystem: Subsystem, configuration: str | None = None) -> str:
    """The configuration as Graphviz DOT text: one cluster per RTPU, one edge per link."""
    d = diagram(subsystem, configuration)
    lines = [
        f"digraph {_q(d.subsystem + ' / ' + d.configuration)} {{",
        "  rankdir=LR;",
        f"  label={_q(f'subsystem {d.subsystem}, configuration {d.configuration}')};",
        '  labelloc="t";',
        '  fontname="Helvetica";',
        '  node [shape=box, style="rounded,filled", fillcolor="white", fontname="Helvetica"];',
        '  edge [fontname="Helvetica", fontsize=10];',
    ]
    for rtpu, tasks in d.rtpus.items():
        lines.append(f"  subgraph {_q(f'cluster_{rtpu}')} {{")
        lines.append(f"    label={_q(rtpu)};")
        lines.append('    style="rounded,filled"; fillcolor="#eef2f8"; color="#9aa8bd";')
        for task in tasks:
            label = f"{task}\n({d.modules[task]})"
            lines.append(f"    {_q(task)} [label={_q(label)}];")
        lines.append("  }")
    if d.has_job_control:
        lines.append(f'  {_q(JOB_CONTROL)} [shape=ellipse, style="filled", fillcolor="#e8f4e8", fontsize=10];')
    for device, driver in d.devices.items():
        label = _q(f"{device} ({driver})")
        lines.append(f'  {_q(_device_id(device))} [label={label}, shape=cylinder, style="filled", fillcolor="#f6efe4"];')
    for link in d.links:
        attrs = [f"label={_q(link.variable)}"]
        if link.const:
            attrs.append("style=dashed")
        if link.job:
            attrs.append('color="#3a7d3a"')
        lines.append(f"  {_q(link.source)} -> {_q(link.target)} [{', '.join(attrs)}];")
    for device, task in d.uses:
        lines.append(f"  {_q(_device_id(device))} -> {_q(task)} [style=dotted, dir=none];")
    lines.append("}")
    return "\n".join(lines) + "\n"


# --- drawing with matplotlib ------------------------------------------------------------------

# Sizes in layout units; the figure maps one unit to UNIT_INCHES.
UNIT_INCHES = 0.9
_CHAR = 0.115  # width of one character of the node font, in units
_NODE_H = 0.95
_COL_GAP = 2.3  # between the columns of nodes: room for the labels
_ROW_GAP = 0.9  # between nodes stacked in one column of a band
_BAND_PAD = 0.45
_BAND_GAP = 0.7


@dataclass
class _Node:
    name: str
    text: str
    kind: str  # task, job, device
    x: float = 0.0
    y: float = 0.0
    w: float = 0.0
    h: float = _NODE_H


def layers(d: Diagram) -> dict[str, int]:
    """Column of every task (and of job control, column 0): longest path over the every-cycle links.

    Control loops are cycles (a controller and its robot feed each other); they are broken by
    the greedy ordering of Eades, Lin and Smyth (sinks to the right, sources to the left, else
    the node with the most outputs over inputs), which leaves few links pointing backwards.
    Const links are ignored.
    """
    nodes = ([JOB_CONTROL] if d.has_job_control else []) + d.tasks
    edges = {(link.source, link.target) for link in d.links if not link.const and link.source != link.target}
    left: list[str] = []
    right: list[str] = []
    rest = list(nodes)
    while rest:
        changed = True
        while changed:
            changed = False
            for n in list(rest):
                if not any((n, m) in edges for m in rest if m != n):  # a sink
                    right.insert(0, n)
                    rest.remove(n)
                    changed = True
            for n in list(rest):
                if not any((m, n) in edges for m in rest if m != n):  # a source
                    left.append(n)
                    rest.remove(n)
                    changed = True
        if rest:
            def surplus(n: str) -> int:
                return sum((n, m) in edges for m in rest) - sum((m, n) in edges for m in rest)

            best = max(rest, key=lambda n: (n == JOB_CONTROL, surplus(n), -nodes.index(n)))
            left.append(best)
            rest.remove(best)
    order = left + right
    position = {n: i for i, n in enumerate(order)}
    first = 1 if d.has_job_control else 0
    layer = {n: (0 if n == JOB_CONTROL else first) for n in nodes}
    for n in order:
        for m in order[position[n] + 1:]:
            if (n, m) in edges:
                layer[m] = max(layer[m], layer[n] + 1)
    return layer


def _layout(d: Diagram) -> tuple[dict[str, _Node], list[tuple[str, float, float, float, float]],
                                 tuple[float, float, float, float]]:
    """Node boxes and RTPU bands (name, x0, y0, x1, y1) in layout units, and the extent."""
    layer = layers(d)
    nodes: dict[str, _Node] = {}
    for task in d.tasks:
        text = f"{task}\n({d.modules[task]})"
        nodes[task] = _Node(task, text, "task", w=_width(text))
    if d.has_job_control:
        nodes[JOB_CONTROL] = _Node(JOB_CONTROL, JOB_CONTROL, "job", w=_width(JOB_CONTROL), h=0.7)
    for device, driver in d.devices.items():
        text = f"{device} ({driver})"
        nodes[_device_id(device)] = _Node(_device_id(device), text, "device", w=_width(text), h=0.7)
    columns = max(layer.values(), default=0) + 1
    widths = [0.0] * columns
    for name, col in layer.items():
        widths[col] = max(widths[col], nodes[name].w)
    centers = []
    x = 0.0
    for w in widths:
        centers.append(x + w / 2)
        x += w + _COL_GAP
    for name, col in layer.items():
        nodes[name].x = centers[col]
    # RTPUs are horizontal bands, top to bottom in declared order; a column's tasks of one
    # RTPU stack inside its band
    bands: list[tuple[str, float, float, float, float]] = []
    top = 0.0
    for rtpu, tasks in d.rtpus.items():
        per_column: dict[int, list[str]] = {}
        for task in tasks:
            per_column.setdefault(layer[task], []).append(task)
        rows = max(len(v) for v in per_column.values())
        height = rows * _NODE_H + (rows - 1) * _ROW_GAP + 2 * _BAND_PAD + 0.35  # room for the RTPU's name
        for members in per_column.values():
            for i, task in enumerate(members):
                # centre the stack in the band, below the name
                span = len(members) * _NODE_H + (len(members) - 1) * _ROW_GAP
                start = top - 0.35 - _BAND_PAD - (rows * _NODE_H + (rows - 1) * _ROW_GAP - span) / 2
                nodes[task].y = start - _NODE_H / 2 - i * (_NODE_H + _ROW_GAP)
        x0 = min(nodes[t].x - nodes[t].w / 2 for t in tasks) - _BAND_PAD
        x1 = max(nodes[t].x + nodes[t].w / 2 for t in tasks) + _BAND_PAD
        bands.append((rtpu, x0, top - height, x1, top))
        top -= height + _BAND_GAP
    if d.has_job_control:
        readers = [link.target for link in d.links if link.job]
        nodes[JOB_CONTROL].y = sum(nodes[t].y for t in readers) / len(readers)
    # devices below the bands, under the tasks that use them
    bottom = top + _BAND_GAP - 0.6
    placed: list[_Node] = []
    for device in d.devices:
        node = nodes[_device_id(device)]
        users = [task for dev, task in d.uses if dev == device]
        node.x = sum(nodes[t].x for t in users) / len(users)
        node.y = bottom - node.h / 2
        for other in placed:  # side by side if two devices would overlap
            if abs(other.x - node.x) < (other.w + node.w) / 2 + 0.4:
                node.x = other.x + (other.w + node.w) / 2 + 0.4
        placed.append(node)
    xs = [n.x - n.w / 2 for n in nodes.values()] + [b[1] for b in bands]
    xe = [n.x + n.w / 2 for n in nodes.values()] + [b[3] for b in bands]
    ys = [n.y - n.h / 2 for n in nodes.values()] + [b[2] for b in bands]
    ye = [n.y + n.h / 2 for n in nodes.values()] + [b[4] for b in bands]
    return nodes, bands, (min(xs), min(ys), max(xe), max(ye))


def _width(text: str) -> float:
    return max(len(line) for line in text.splitlines()) * _CHAR + 0.5


def _grouped(d: Diagram) -> list[tuple[str, str, bool, bool, list[str]]]:
    """Links between the same two nodes of the same style, as one arrow with their variables."""
    groups: dict[tuple[str, str, bool, bool], list[str]] = {}
    for link in d.links:
        groups.setdefault((link.source, link.target, link.const, link.job), []).append(link.variable)
    return [(s, t, c, j, v) for (s, t, c, j), v in groups.items()]


def _render(d: Diagram, path: Path, fmt: str) -> None:
    from matplotlib.figure import Figure
    from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

    nodes, bands, (x0, y0, x1, y1) = _layout(d)
    margin = 0.6
    title_room = 0.9
    legend_room = 0.6
    x0, x1 = x0 - margin, x1 + margin
    y0, y1 = y0 - margin - legend_room, y1 + margin + title_room
    fig = Figure(figsize=((x1 - x0) * UNIT_INCHES, (y1 - y0) * UNIT_INCHES))
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.text((x0 + x1) / 2, y1 - 0.45, f"subsystem '{d.subsystem}', configuration '{d.configuration}'",
            ha="center", va="center", fontsize=12, fontweight="bold")
    for rtpu, bx0, by0, bx1, by1 in bands:
        ax.add_patch(FancyBboxPatch((bx0, by0), bx1 - bx0, by1 - by0, boxstyle="round,pad=0,rounding_size=0.3",
                                    facecolor="#eef2f8", edgecolor="#9aa8bd", linewidth=1.0, zorder=0))
        ax.text(bx0 + 0.25, by1 - 0.25, rtpu, ha="left", va="top", fontsize=10, fontweight="bold", color="#4a5a75", zorder=1)
    patches = {}
    styles: dict[str, dict[str, Any]] = {
        "task": dict(facecolor="white", edgecolor="#333333", boxstyle="round,pad=0,rounding_size=0.15"),
        "job": dict(facecolor="#e8f4e8", edgecolor="#3a7d3a", boxstyle="round,pad=0,rounding_size=0.3"),
        "device": dict(facecolor="#f6efe4", edgecolor="#8a6d3b", boxstyle="round,pad=0,rounding_size=0.05"),
    }
    for node in nodes.values():
        patch = FancyBboxPatch((node.x - node.w / 2, node.y - node.h / 2), node.w, node.h, linewidth=1.2, zorder=3,
                               **styles[node.kind])
        ax.add_patch(patch)
        patches[node.name] = patch
        if node.kind == "task":
            name, module = node.text.split("\n")
            ax.text(node.x, node.y + 0.14, name, ha="center", va="center", fontsize=10, fontweight="bold", zorder=4)
            ax.text(node.x, node.y - 0.2, module, ha="center", va="center", fontsize=8, color="#555555", zorder=4)
        else:
            ax.text(node.x, node.y, node.text, ha="center", va="center", fontsize=9, zorder=4)
    drawn: list[list[tuple[float, float]]] = []  # sample points of every arrow so far
    for device, task in d.uses:
        a, b = nodes[_device_id(device)], nodes[task]
        rad, points = _route(nodes, a, b, drawn)
        drawn.append(points)
        ax.add_patch(FancyArrowPatch((a.x, a.y), (b.x, b.y), patchA=patches[a.name], patchB=patches[b.name],
                                     connectionstyle=f"arc3,rad={rad}", arrowstyle="-", linestyle=":", linewidth=1.5,
                                     color="#8a6d3b", zorder=2))
    routes = []
    for source, target, const, job, variables in sorted(_grouped(d), key=lambda g: (g[3], g[2], g[0], g[1])):
        a, b = nodes[source], nodes[target]
        rad, points = _route(nodes, a, b, drawn)
        drawn.append(points)
        routes.append((a, b, const, job, variables, rad, points))
    taken: list[tuple[float, float, float, float]] = []
    for a, b, const, job, variables, rad, points in routes:
        color = "#3a7d3a" if job else ("#7a7a7a" if const else "#1f3b66")
        ax.add_patch(FancyArrowPatch((a.x, a.y), (b.x, b.y), patchA=patches[a.name], patchB=patches[b.name],
                                     connectionstyle=f"arc3,rad={rad}", arrowstyle="-|>", mutation_scale=14,
                                     linestyle="--" if const else "-", linewidth=1.3, color=color, zorder=2,
                                     shrinkA=2, shrinkB=2))
        text = ", ".join(variables)
        lx, ly = _label_spot(text, points, taken, nodes, drawn)
        ax.text(lx, ly, text, ha="center", va="center", fontsize=8, color=color, zorder=5,
                bbox=dict(boxstyle="round,pad=0.15", facecolor="white", edgecolor="none", alpha=0.9))
    ax.text(x0 + 0.3, y0 + 0.3, "solid: every cycle    dashed: const (at init)    green: from job control    dotted: device",
            ha="left", va="bottom", fontsize=8, color="#555555")
    metadata = {"Date": None} if fmt == "svg" else {}
    fig.savefig(path, format=fmt, metadata=metadata, dpi=110)


_SAMPLES = 48


def _curve(a: _Node, b: _Node, rad: float) -> list[tuple[float, float]]:
    """Points along matplotlib's arc3 connection from a's centre to b's (a quadratic Bézier)."""
    dx, dy = b.x - a.x, b.y - a.y
    cx, cy = (a.x + b.x) / 2 + rad * dy, (a.y + b.y) / 2 - rad * dx
    points = []
    for i in range(_SAMPLES + 1):
        t = i / _SAMPLES
        u = 1 - t
        points.append((u * u * a.x + 2 * t * u * cx + t * t * b.x, u * u * a.y + 2 * t * u * cy + t * t * b.y))
    return points


def _inside(x: float, y: float, node: _Node, margin: float) -> bool:
    return abs(x - node.x) < node.w / 2 + margin and abs(y - node.y) < node.h / 2 + margin


def _route(nodes: dict[str, _Node], a: _Node, b: _Node,
           drawn: list[list[tuple[float, float]]]) -> tuple[float, list[tuple[float, float]]]:
    """The bend of an arrow from a to b: through no other box, away from the arrows drawn so far,
    and as straight as that allows."""
    import numpy as np

    others = [n for n in nodes.values() if n is not a and n is not b]
    centres = np.array([(n.x, n.y) for n in others]).reshape(-1, 2)
    halves = np.array([(n.w / 2 + 0.15, n.h / 2 + 0.15) for n in others]).reshape(-1, 2)
    previous = np.array([p for curve in drawn for p in curve]).reshape(-1, 2)
    best: tuple[float, float, list[tuple[float, float]]] | None = None
    for rad in (0.08, -0.08, 0.2, -0.2, 0.32, -0.32, 0.45, -0.45, 0.6, -0.6):
        points = _curve(a, b, rad)
        inner = np.array([p for p in points if not _inside(*p, a, 0.05) and not _inside(*p, b, 0.05)]).reshape(-1, 2)
        hits = (int(np.all(np.abs(inner[:, None, :] - centres[None, :, :]) < halves[None, :, :], axis=2).sum())
                if len(centres) else 0)
        crowd = 0
        if len(previous) and len(inner):
            nearest = np.sqrt(((inner[:, None, :] - previous[None, :, :]) ** 2).sum(axis=2)).min(axis=1)
            crowd = int((nearest < 0.3).sum())
        score = 50 * hits + crowd + 4 * abs(rad)
        if best is None or score < best[0]:
            best = (score, rad, points)
    assert best is not None
    return best[1], best[2]


def _label_spot(text: str, points: list[tuple[float, float]], taken: list[tuple[float, float, float, float]],
                nodes: dict[str, _Node], drawn: list[list[tuple[float, float]]]) -> tuple[float, float]:
    """A point on the arrow for its label: near the middle, clear of boxes, other labels and,
    if it can be, other arrows."""
    w, h = len(text) * 0.095 + 0.25, 0.34
    mid = len(points) // 2
    best: tuple[float, float, float] | None = None
    for offset in sorted(range(-14, 15), key=abs):
        x, y = points[mid + offset]
        box = (x - w / 2, y - h / 2, x + w / 2, y + h / 2)
        blocked = any(_overlap(box, t) for t in taken) or any(
            _overlap(box, (n.x - n.w / 2, n.y - n.h / 2, n.x + n.w / 2, n.y + n.h / 2)) for n in nodes.values()
        )
        crossing = sum(1 for other in drawn if other is not points
                       for px, py in other if box[0] < px < box[2] and box[1] < py < box[3])
        score = 100 * blocked + 3 * crossing + abs(offset)
        if best is None or score < best[0]:
            best = (score, x, y)
    assert best is not None
    _, x, y = best
    taken.append((x - w / 2, y - h / 2, x + w / 2, y + h / 2))
    return x, y


def _overlap(p: tuple[float, float, float, float], q: tuple[float, float, float, float]) -> bool:
    return p[0] < q[2] and q[0] < p[2] and p[1] < q[3] and q[1] < p[3]


def draw(subsystem: Subsystem, configuration: str | None, path: str | Path) -> Path:
    """Write the configuration's diagram to `path`: `.dot` Graphviz text, `.png` or `.svg` a picture."""
    target = Path(path)
    suffix = target.suffix.lower()
    if suffix not in SUFFIXES:
        raise ValueError(f"cannot draw to '{target.name}': the file name must end in one of {', '.join(SUFFIXES)}")
    if suffix == ".dot":
        text = to_dot(subsystem, configuration)
        target.write_text(text, encoding="utf-8")
        return target
    d = diagram(subsystem, configuration)
    _render(d, target, suffix[1:])
    return target
