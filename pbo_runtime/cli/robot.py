"""`pbo robot MODEL|FILE`: an arm as pbo sees it, offline, and the gains a bandwidth asks of each joint.

The robot is loaded the way the plant loads it (`describe_robot` of the `mujoco_arm` plant type:
a registered name, a URDF or MJCF path, a `package://` URI), so the joints, limits and masses are
the ones a run would use. Each joint's reflected inertia range comes from `objects.arm_inertia`;
with `--bandwidth`, the gains `pid_joint` would make (`objects.arm_inertia.arm_gains`: for the
heaviest pose, or a lighter one where the lightest would be poorly damped), the torque each asks
for a step, and the sampled loop's verdict at `--period` (docs/robots.md, "Gains for your arm").
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rich.console import Console

PLANT_TYPE = "mujoco_arm"


def run(args: argparse.Namespace, console: Console, errors: Console) -> int:
    problem = _argument_problem(args)
    if problem:
        errors.print(f"error: {problem}", markup=False)
        return 1
    try:
        robot = load(args.model, {"ee": args.ee} if args.ee else {})
    except ValueError as exc:
        hint = getattr(exc, "hint", "")
        errors.print(f"error: {exc}" + (f"\n  hint: {hint}" if hint else ""), markup=False)
        return 1
    report = describe(robot, args)
    if args.format == "json":
        console.print_json(json.dumps(report))
    else:
        console.print("\n".join(text_lines(report)), markup=False, soft_wrap=True)
    return 0


def _argument_problem(args: argparse.Namespace) -> str:
    if args.bandwidth is not None and not (math.isfinite(args.bandwidth) and args.bandwidth > 0):
        return f"--bandwidth must be > 0 rad/s, got: {args.bandwidth:g}"
    if not (math.isfinite(args.damping) and args.damping > 0):
        return f"--damping must be > 0, got: {args.damping:g}"
    if not (math.isfinite(args.period) and args.period > 0):
        return f"--period must be > 0 s, got: {args.period:g}"
    if not (math.isfinite(args.integral_time) and args.integral_time >= 0):
        return f"--integral-time must be >= 0 s (0: none), got: {args.integral_time:g}"
    if not (math.isfinite(args.step) and args.step >= 0):
        return f"--step must be >= 0, got: {args.step:g}"
    return ""


def load(model: str, options: dict[str, Any]) -> Any:
    """The robot a plant would simulate for `model` (a path is relative to the current folder)."""
    from pbo_runtime.objects import registry
    from pbo_runtime.objects.arm import is_robot_file

    base_dir = Path.cwd()
    if is_robot_file(model) and not model.startswith("package://"):
        model = str(Path(model).resolve())
    return registry.plant_class(PLANT_TYPE).describe_robot(model, str(base_dir), options)


def describe(robot: Any, args: argparse.Namespace) -> dict[str, Any]:
    """The robot as JSON-able data: joints with limits, masses, inertia ranges (and gains)."""
    from pbo_runtime.objects.arm import Arm
    from pbo_runtime.objects.arm_inertia import arm_gains, inertia_range
    from pbo_runtime.objects.joint_loop import LoopGains, analyse

    arm, ee = robot.arm, robot.ee
    inertia = inertia_range(arm, ee)
    joints = []
    if args.bandwidth is not None:
        kp, kd, ki, design = arm_gains(inertia, args.bandwidth, args.damping, args.integral_time, args.period)
    for j, limits in enumerate(robot.limit_rows()):
        row: dict[str, Any] = {**limits, "mass": float(arm[j, Arm.MASS]), "inertia_min": float(inertia.low[j]),
                               "inertia_max": float(inertia.high[j]), "inertia_coupled_min": float(inertia.coupled_low[j])}
        if args.bandwidth is not None:
            gains = LoopGains(float(kp[j]), float(kd[j]), float(ki[j]))
            verdict = analyse(float(inertia.coupled_low[j]), float(inertia.high[j]), gains, args.period,
                              viscous=float(inertia.viscous[j]))
            torque = gains.kp * args.step
            row.update(design_inertia=float(design[j]), kp=gains.kp, kd=gains.kd, ki=gains.ki, step_torque=torque,
                       within_effort=bool(torque <= row["effort"]), stable=verdict.stable,
                       damping_ratio=verdict.damping if verdict.stable else None)
        joints.append(row)
    ee_parent = int(ee[0])
    report: dict[str, Any] = {
        "robot": robot.name, "source": robot.source, "ndof": robot.ndof, "end_effector": robot.ee_name,
        "end_effector_joint": robot.joint_names[ee_parent] if ee_parent >= 0 else None,
        "mass": float(arm[:, Arm.MASS].sum()), "joints": joints,
    }
    if args.bandwidth is not None:
        report["gains"] = {"bandwidth": args.bandwidth, "damping": args.damping, "integral_time": args.integral_time,
                           "step": args.step, "period": args.period}
    return report


def text_lines(report: dict[str, Any]) -> list[str]:
    """The report as a table a joint a line."""
    from pbo_runtime.objects.joint_loop import LOW_DAMPING

    joints = report["joints"]
    lines = [f"robot {report['robot']}: {report['ndof']} joints, end effector {report['end_effector']}"
             + (f" (moves with {report['end_effector_joint']})" if report["end_effector_joint"] else "")
             + f", {report['mass']:.4g} kg moving",
             f"  from {report['source']}",
             "  reflected inertia over the workspace, kg m² (kg): the mass matrix's diagonal (armature included), "
             "and its least with the other joints free, 1 / (M⁻¹)_jj"]
    header: tuple[str, ...] = ("joint", "effort", "velocity", "range", "mass", "inertia min", "inertia max", "free min")
    cells: list[tuple[str, ...]] = []
    for r in joints:
        force = "N" if r["unit"] == "m" else "N m"
        cells.append((str(r["joint"]), f"{r['effort']:g} {force}",
                      f"{r['velocity']:g} {r['unit']}/s" if r["velocity"] is not None else "none",
                      f"[{r['lower']:.4g}, {r['upper']:.4g}] {r['unit']}" if r["lower"] is not None else "continuous",
                      f"{r['mass']:.4g} kg", f"{r['inertia_min']:.4g}", f"{r['inertia_max']:.4g}",
                      f"{r['inertia_coupled_min']:.4g}"))
    lines += _table(header, cells)
    gains = report.get("gains")
    if gains:
        integral = f", integral time {gains['integral_time']:g} s" if gains["integral_time"] else ""
        lines.append(f"  gains for bandwidth {gains['bandwidth']:g} rad/s, damping {gains['damping']:g}{integral} for inertia I "
                     f"(kp = I w², kd = 2 ζ I w - b, b the joint friction; I the heaviest, or lighter where a light "
                     f"pose would ring); the loop at a {gains['period'] * 1e3:g} ms period, one period of delay; "
                     f"torque for a {gains['step']:g} step:")
        header = ("joint", "I", "kp", "kd", "ki", "step torque", "loop")
        cells = []  # of the gains table
        for r in joints:
            over = "" if r["within_effort"] else f" > effort {r['effort']:g}"
            if not r["stable"]:
                loop = "UNSTABLE at a light pose: lower the bandwidth"
            elif r["damping_ratio"] < LOW_DAMPING:
                loop = f"damping ratio {r['damping_ratio']:.2f}: rings"
            else:
                loop = f"damping ratio {r['damping_ratio']:.2f}"
            cells.append((str(r["joint"]), f"{r['design_inertia']:.4g}", f"{r['kp']:.4g}", f"{r['kd']:.4g}", f"{r['ki']:.4g}",
                          f"{r['step_torque']:.4g}{over}", loop))
        lines += _table(header, cells)
    return lines


def _table(header: tuple[str, ...], cells: Sequence[tuple[str, ...]]) -> list[str]:
    rows = [header, *cells]
    widths = [max(len(row[i]) for row in rows) for i in range(len(header))]
    return ["    " + "  ".join(cell.ljust(width) for cell, width in zip(row, widths, strict=True)).rstrip() for row in rows]
