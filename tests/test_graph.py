"""Block diagrams of configurations (TR Figures 8, 10): DOT text, and pictures drawn with matplotlib."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.reports.graph import JOB_CONTROL, diagram, draw, layers, to_dot

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "configs" / "pid_joint.yaml"


@pytest.fixture(scope="module")
def subsystem():
    return load_subsystem(DEMO)


def _edges(dot: str) -> list[tuple[str, str, str]]:
    """(source, target, attributes) of every edge line."""
    return re.findall(r'^\s*"([^"]+)" -> "([^"]+)" \[(.*)\];$', dot, flags=re.M)


def test_dot_has_a_cluster_per_rtpu_with_its_tasks(subsystem):
    dot = to_dot(subsystem, "joint_pid")
    assert dot.startswith("digraph ") and dot.rstrip().endswith("}")
    for rtpu in ("rtpu0", "rtpu1"):
        assert f'subgraph "cluster_{rtpu}" {{' in dot
    cluster1 = dot.split('subgraph "cluster_rtpu1"')[1].split("}")[0]
    assert '"robot" [label="robot\\n(robot_torque)"]' in cluster1
    cluster0 = dot.split('subgraph "cluster_rtpu0"')[1].split("}")[0]
    assert all(f'"{t}"' in cluster0 for t in ("traj", "pid", "logger"))


def test_dot_edges_are_links_labelled_with_their_variables(subsystem):
    edges = _edges(to_dot(subsystem, "joint_pid"))
    assert ("robot", "pid", 'label="q_m"') in edges  # every cycle: solid
    assert ("robot", "pid", 'label="ARM", style=dashed') in edges  # out-const -> in-const
    assert ("pid", "robot", 'label="tau_u"') in edges
    job = [e for e in edges if e[0] == JOB_CONTROL]
    assert [(s, t) for s, t, _ in job] == [(JOB_CONTROL, "traj")] and 'label="q_d"' in job[0][2]
    assert ("device:arm", "robot", "style=dotted, dir=none") in edges
    assert '"device:arm" [label="arm (mujoco_arm)"' in to_dot(subsystem)


def test_diagram_and_layers(subsystem):
    d = diagram(subsystem)  # the first configuration
    assert d.configuration == "joint_pid" and d.has_job_control
    assert d.rtpus == {"rtpu0": ["traj", "pid", "logger"], "rtpu1": ["robot"]}
    layer = layers(d)
    assert layer[JOB_CONTROL] == 0
    assert layer["traj"] < layer["pid"] < layer["logger"]  # reference -> controller -> logger, left to right


def test_an_unknown_configuration_names_the_valid_ones(subsystem):
    with pytest.raises(ValueError, match="joint_pid"):
        to_dot(subsystem, "nope")


@pytest.mark.parametrize("suffix", [".png", ".svg", ".dot"])
def test_draw_writes_the_file(subsystem, tmp_path, suffix):
    path = draw(subsystem, "joint_pid", tmp_path / f"joint_pid{suffix}")
    data = path.read_bytes()
    assert len(data) > 1000
    if suffix == ".png":
        assert data.startswith(b"\x89PNG\r\n\x1a\n")
    elif suffix == ".svg":
        head = data[:400].decode()
        assert head.startswith("<?xml") and "<svg" in data[:2000].decode()
    else:
        assert data.decode() == to_dot(subsystem, "joint_pid")


def test_draw_refuses_an_unknown_suffix(subsystem, tmp_path):
    with pytest.raises(ValueError, match=r"\.dot, \.png, \.svg"):
        draw(subsystem, "joint_pid", tmp_path / "joint_pid.pdf")
