"""What the robot interface's limits cost a cycle: clipping every command and watching for divergence.

The robot interface (`robot_torque`, `robot_position`) runs as a real Task on a real table over
an in-process MuJoCo plant stepped once per cycle; each cycle's `run_cycle` (the table transfers,
the driver's read and write, and the limit work) is timed with `perf_counter_ns`. The baseline is
the same task with its limit arrays swapped for a stand-in that clips and checks nothing, timed in
blocks interleaved with the contender's, so both see the same machine. Torque mode is timed with
a command within the limits (the usual cycle) and one past them on every joint, its sign turned
each cycle so the arm only trembles (clipped and counted; the count is reset each cycle so the
fault never comes).

    python -m bench.robot_limits [--cycles 2000] [--rounds 10]
"""

from __future__ import annotations

import argparse
import statistics
import time
import uuid
from typing import Any

import numpy as np

from bench._common import Section, Table, Target
from drivers.mujoco_arm.driver import MujocoArmDriver
from drivers.mujoco_arm.plant import MujocoArmPlant
from modules.robot_position import RobotPosition
from modules.robot_torque import RobotTorque
from pbo_runtime import Arm
from pbo_runtime.config.model import DeviceSpec, PortBinding, TaskSpec, VariableSpec
from pbo_runtime.table.table import StateTable, TableLayout
from pbo_runtime.task.lifecycle import Task

PERIOD = 0.001  # s, the robot interface's in the shipped configurations
# the added time of a cycle, as a share of its period, the limits may take at most
SHARE_OF_PERIOD = 0.01


class NoLimits:
    """The baseline: the limit arrays' per-cycle calls, doing only what the cycle needs without limits."""

    def __init__(self, limits: Any) -> None:
        self.velocity, self.q_min, self.q_max = limits.velocity, limits.q_min, limits.q_max

    def outside(self, q: np.ndarray, qd: np.ndarray) -> bool:
        return False

    def saturate_torque(self, tau: np.ndarray, out: np.ndarray, now: float = 0.0) -> bool:
        np.copyto(out, tau)
        return False

    def limit_position(self, q_r: np.ndarray, previous: np.ndarray, step: np.ndarray, out: np.ndarray) -> None:
        np.copyto(out, q_r)

    def reset(self) -> None:
        pass


def _task(module: type, plant: MujocoArmPlant, table: StateTable, n: int) -> Task:
    mode = "torque" if module is RobotTorque else "position"
    dims = {"NDOF": n}
    bindings = tuple(PortBinding(p, p.variable, p.resolved_shape(dims)) for p in module.ports())
    spec = TaskSpec(name="robot", module=module.__name__, rtpu="rtpu0", period=PERIOD, bindings=bindings, resources=("arm",))
    task = Task(spec, module, table, dims, devices={"arm": DeviceSpec("arm", "mujoco_arm", True, {"mode": mode})},
                opener=lambda s, _t: MujocoArmDriver(plant.name, s.options))
    if not task.spawn(0.0) or not task.turn_on(0.0):
        raise RuntimeError(task.last_error)
    return task


def measure(case: str, cycles: int, rounds: int) -> dict[str, list[float]]:
    """Cycle times (µs) of one case, with limits and without, interleaved by blocks of `cycles`."""
    module = RobotPosition if case == "position" else RobotTorque
    plant = MujocoArmPlant(f"/pbo.bench.{uuid.uuid4().hex[:8]}.plant", "redundant7", PERIOD, {"command_timeout": 0})
    n = plant.ndof
    names = [("NDOF", "int32", ()), ("ARM", "float64", (n, Arm.WIDTH)), ("EE", "float64", (Arm.EE_WIDTH,)),
             ("q_m", "float64", (n,)), ("qd_m", "float64", (n,)), ("tau_u", "float64", (n,)), ("q_r", "float64", (n,))]
    table = StateTable.create(TableLayout.build([VariableSpec(v, i, t, s) for i, (v, t, s) in enumerate(names)], 2),
                              f"/pbo.bench.{uuid.uuid4().hex[:8]}.table")
    times: dict[str, list[float]] = {"with limits": [], "without": []}
    try:
        task = _task(module, plant, table, n)
        real = task.module._limits
        command, value = ("q_r", plant.robot.q0) if case == "position" else \
            ("tau_u", np.full(n, 1e6) if case == "torque, saturated" else np.zeros(n))
        table.write(command, value, when=0.0)
        turn = -1.0 if case == "torque, saturated" else 1.0
        k = 0
        for _ in range(rounds):
            for name, limits in (("with limits", real), ("without", NoLimits(real))):
                task.module._limits = limits
                for _ in range(cycles):
                    k += 1
                    value *= turn
                    table.write(command, value, when=k * PERIOD)
                    start = time.perf_counter_ns()
                    task.run_cycle(k * PERIOD)
                    times[name].append((time.perf_counter_ns() - start) / 1e3)
                    real.reset()  # a saturated command is counted, never long enough for the fault
                    plant.step()
        task.kill()
    finally:
        table.close()
        plant.close()
    return times


def run(cycles: int = 2000, rounds: int = 10) -> Section:
    section = Section(
        key="robot_limits", title="The robot's limits in the robot interface's cycle", command="python -m bench.robot_limits",
        method=(f"The robot interface runs as a real Task on a real table over an in-process MuJoCo plant (the built-in "
                f"7-joint arm), one plant step per cycle; each `run_cycle` is timed. Baseline: the same task with its limit "
                f"checks swapped for a stand-in that clips and checks nothing, in blocks of {cycles} cycles interleaved with "
                f"the contender's ({rounds} rounds)."),
        limits="The plant's step runs between cycles and is not timed; a real run adds the executive's own work around it.")
    table = Table(["case", "p50 without (µs)", "p50 with (µs)", "added p50 (µs)", "p99 without (µs)", "p99 with (µs)"],
                  numeric=(1, 2, 3, 4, 5), caption="One robot interface cycle, with and without the limit checks:")
    added_worst = 0.0
    for case in ("torque, within", "torque, saturated", "position"):
        times = measure(case, cycles, rounds)
        base, with_ = (np.array(times[k]) for k in ("without", "with limits"))
        added = statistics.median(with_) - statistics.median(base)
        added_worst = max(added_worst, added)
        table.add(case, f"{np.median(base):.1f}", f"{np.median(with_):.1f}", f"{added:.1f}",
                  f"{np.percentile(base, 99):.1f}", f"{np.percentile(with_, 99):.1f}")
    section.tables.append(table)
    section.ratios["added p50 / period"] = added_worst * 1e-6 / PERIOD
    section.targets.append(Target("the limit checks' added time per robot interface cycle (p50, the worst case) "
                                  "/ its period (1 ms)",
                                  added_worst * 1e-6 / PERIOD, SHARE_OF_PERIOD))
    return section


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=2000)
    parser.add_argument("--rounds", type=int, default=10)
    args = parser.parse_args()
    print(run(args.cycles, args.rounds).text())


if __name__ == "__main__":
    main()
