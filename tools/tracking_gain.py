"""TR Figure 14's point, printed: computed torque tracks a fast trajectory far better than PID alone.

    .venv/bin/python tools/tracking_gain.py [--seconds 2.5]

It runs `configs/computed_torque.yaml` on the simulated clock (exact and repeatable) in two
configurations over the same fast joint trajectory (2 rad/s, 8 rad/s^2): `combined` (PID +
inverse dynamics as one task) and `pid_alone` (the PID joint controller of Figure 8, with
gravity feed-forward, writing the torque itself), each with a data logger added, and prints
the tracking error |q_r - q_m| (max and RMS over the run) and the ratio.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parent.parent
CONFIG = REPO / "configs" / "computed_torque.yaml"
FAST = {"max_velocity": 2.0, "max_acceleration": 8.0}


def comparison_file(folder: Path) -> Path:
    """The shipped file with a fast trajectory, a logger and a `pid_alone` configuration added."""
    spec = yaml.safe_load(CONFIG.read_text())
    spec["subsystem"] = "ctc_vs_pid"  # its own name: a run of the shipped 'ctc' may be alive beside it
    tasks = spec["tasks"]
    tasks["traj"]["params"] = dict(FAST)
    tasks["pid_alone"] = {"module": "pid_joint", "rtpu": "rtpu0", "period": "1 ms", "ports": {"tau": "tau_u"},
                          "params": {"kp": 400, "kd": 40, "ki": 10, "gravity_feedforward": True}}
    tasks["logger"] = {"module": "data_logger", "rtpu": "rtpu0", "period": "2 ms",
                       "params": {"variables": ["q_m", "q_r"], "path": "tracking.npy"}}
    spec["configurations"] = {
        "combined": ["robot", "traj", "ctc", "logger"],
        "pid_alone": ["robot", "traj", "pid_alone", "logger"],
    }
    path = folder / "computed_torque_vs_pid.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def tracking_errors(seconds: float = 2.5) -> dict[str, dict[str, float]]:
    """Max and RMS of max_j |q_r - q_m| for each configuration, radians."""
    out: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory() as folder:
        path = comparison_file(Path(folder))
        for configuration in ("combined", "pid_alone"):
            run_dir = Path(folder) / configuration
            done = subprocess.run([sys.executable, "-m", "pbo_runtime.cli", "run", str(path), "--config", configuration,
                                   "--clock", "sim", "--duration", repr(seconds), "--no-live", "--out", str(run_dir)],
                                  cwd=folder, capture_output=True, text=True, timeout=300)
            if done.returncode != 0:
                raise RuntimeError(f"{configuration}: pbo run failed:\n{done.stdout}\n{done.stderr}")
            log = np.load(run_dir / "tracking.npy")
            error = np.abs(log["q_r"] - log["q_m"]).max(axis=1)
            out[configuration] = {"max": float(error.max()), "rms": float(np.sqrt(np.mean(error ** 2)))}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=2.5)
    args = parser.parse_args(argv)
    errors = tracking_errors(args.seconds)
    print(f"tracking error on a fast trajectory ({FAST['max_velocity']} rad/s, {FAST['max_acceleration']} rad/s^2), "
          f"{args.seconds:g} s, simulated clock")
    print(f"{'configuration':<26}{'max mrad':>10}{'rms mrad':>10}")
    for name, label in (("pid_alone", "PID alone (Figure 8)"), ("combined", "computed torque (Fig. 14)")):
        print(f"{label:<26}{errors[name]['max'] * 1e3:>10.2f}{errors[name]['rms'] * 1e3:>10.2f}")
    print(f"PID alone / computed torque: max {errors['pid_alone']['max'] / errors['combined']['max']:.1f}x, "
          f"rms {errors['pid_alone']['rms'] / errors['combined']['rms']:.1f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
