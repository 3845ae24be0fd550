"""How `pbo check` scales: generated task sets of 100, 1,000 and 10,000 tasks, timed end to end.

Each generated subsystem is n/3 joint control loops over the real module library (trajectory
generator, PID controller, data logger, each loop with its own variables), spread over 4 RTPUs,
each loop its own configuration (a module runs at most once per configuration).

    python bench/check_scale.py [--sizes 102 1002 10002] [--repeat 3]

(sizes are multiples of 3: each loop is three tasks)
"""

from __future__ import annotations

import argparse
import platform
import statistics
import tempfile
import time
from pathlib import Path

from pbo_runtime._config_loader import check_file


def generate(n_tasks: int) -> str:
    """A legal subsystem of about n_tasks tasks: joint control loops sharing one robot's consts.

    Each loop is a trajectory generator, a PID controller and a data logger of the torque, with
    its own variables (nothing unread, no warning), spread over 4 RTPUs, one configuration each
    (a module runs at most once per configuration).
    """
    lines = [
        f"subsystem: scale{n_tasks}",
        "rtpus: [rtpu0, rtpu1, rtpu2, rtpu3]",
        "bus: {bandwidth: 1 GB/s, lock_overhead: 16 B}",
        "dims: {NDOF: 6}",
        "variables:",
        "  NDOF: {type: int32, initial: 6}",
        "  DH: {type: float64, shape: [NDOF, 4], initial: 0.0}",
        "  DYN: {type: float64, shape: [NDOF, 11], initial: 0.0}",
    ]
    loops = n_tasks // 3
    for i in range(loops):
        lines += [
            f"  q_d{i}: {{type: float64, shape: [NDOF], object: joint_position, initial: 0.0}}",
            f"  q_m{i}: {{type: float64, shape: [NDOF], initial: 0.0}}",
            f"  qd_m{i}: {{type: float64, shape: [NDOF], initial: 0.0}}",
            f"  q_r{i}: {{type: float64, shape: [NDOF]}}",
            f"  qd_r{i}: {{type: float64, shape: [NDOF]}}",
            f"  tau{i}: {{type: float64, shape: [NDOF]}}",
        ]
    lines.append("tasks:")
    for i in range(loops):
        rtpu = f"rtpu{i % 4}"
        lines.append(f"  traj{i}: {{module: joint_trajectory, rtpu: {rtpu}, period: 2 ms, "
                     f"ports: {{q_d: q_d{i}, q_m: q_m{i}, q_r: q_r{i}, qd_r: qd_r{i}}}}}")
        lines.append(f"  pid{i}: {{module: pid_joint, rtpu: {rtpu}, period: 1 ms, params: {{kp: 400, kd: 40, gravity_feedforward: false}}, "
                     f"ports: {{q_r: q_r{i}, qd_r: qd_r{i}, q_m: q_m{i}, qd_m: qd_m{i}, tau: tau{i}}}}}")
        lines.append(f"  log{i}: {{module: data_logger, rtpu: {rtpu}, period: 10 ms, params: {{variables: [tau{i}], path: runs/log{i}.npz}}}}")
    lines.append("configurations:")
    for i in range(loops):
        lines.append(f"  loop{i}: [traj{i}, pid{i}, log{i}]")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[102, 1002, 10002])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    check_file(Path(__file__).resolve().parent.parent / "configs" / "pid_joint.yaml")  # warm imports and the registry
    print(f"pbo check on generated subsystems (best and median of {args.repeat}); "
          f"{platform.machine()}, Python {platform.python_version()}")
    print()
    print("| tasks | YAML lines | best s | median s | µs per task | errors | warnings |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    per_task = []
    with tempfile.TemporaryDirectory() as folder:
        for n in args.sizes:
            path = Path(folder) / f"scale{n}.yaml"
            text = generate(n)
            path.write_text(text)
            times = []
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                result = check_file(path)
                times.append(time.perf_counter() - t0)
            best = min(times)
            per_task.append(best / n)
            print(f"| {n:,} | {text.count(chr(10)):,} | {best:.3f} | {statistics.median(times):.3f} | "
                  f"{best / n * 1e6:.0f} | {len(result.errors)} | {len(result.warnings)} |")
    print()
    growth = per_task[-1] / per_task[0]
    print(f"time per task, largest vs smallest: {growth:.2f}x (1.0 = linear)")
    largest = max(args.sizes)
    if largest >= 10000:
        best_largest = per_task[args.sizes.index(largest)] * largest
        print(f"{largest:,} tasks: {best_largest:.2f} s (target for 10,000: under 2 s) -> {'met' if best_largest < 2.0 else 'NOT met'}")


if __name__ == "__main__":
    main()
