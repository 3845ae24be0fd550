"""The scripted trackball of Cartesian teleoperation (TR Figure 10)."""

from __future__ import annotations

import numpy as np
import pytest

from modules.trackball_input import TrackballInput
from pbo_runtime import ParamError
from pbo_runtime.task.lifecycle import Task
from tests.support import task_spec, variables

POSE = np.array([0.5, -0.1, 0.2, 0.0, -0.4, 0.0])


def run(make_table, params, times):
    table = make_table(variables(("x_m", "float64", (6,)), ("x_d", "float64", (6,))))
    table.write("x_m", POSE, when=0)
    task = Task(task_spec(TrackballInput, params=params), TrackballInput, table)
    assert task.spawn(0.0), task.last_error
    task.turn_on(10.0)
    out = []
    for t in times:
        task.run_cycle(10.0 + t)
        out.append(table.read("x_d")[0] - POSE)
    return np.array(out)


def test_the_desired_pose_follows_the_waypoints_from_where_the_arm_was(make_table):
    offsets = run(make_table, {"script": [[1.0, 0.1, 0, 0, 0, 0, 0], [3.0, 0.1, 0, 0.2, 0, 0, 0]]}, [0.5, 1.0, 2.0, 3.0, 9.0])
    assert offsets[:, 0] == pytest.approx([0.05, 0.1, 0.1, 0.1, 0.1])
    assert offsets[:, 2] == pytest.approx([0.0, 0.0, 0.1, 0.2, 0.2])  # held after the last waypoint


def test_waypoints_can_come_from_a_csv_file_with_a_header(make_table, tmp_path):
    path = tmp_path / "session.csv"
    path.write_text("t,dx,dy,dz,rx,ry,rz\n1.0,0,0.1,0,0,0,0\n")
    offsets = run(make_table, {"file": str(path)}, [0.5, 2.0])
    assert offsets[:, 1] == pytest.approx([0.05, 0.1])


@pytest.mark.parametrize(("params", "message"), [
    ({}, r"give exactly one of script"),
    ({"script": [[1.0, 0, 0]]}, r"each waypoint is 7 numbers"),
    ({"script": [[2.0, 0, 0, 0, 0, 0, 0], [1.0, 0, 0, 0, 0, 0, 0]]}, r"waypoint times must start at >= 0 and increase"),
])
def test_bad_scripts_are_refused(params, message):
    with pytest.raises(ParamError, match=message):
        TrackballInput.build_params(params)
