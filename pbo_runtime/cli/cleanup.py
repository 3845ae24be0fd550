"""`pbo clean`: your shared memory, semaphores and queues left by dead runs, removed (`supervisor.cleanup`)."""

from __future__ import annotations

import argparse
import os

from rich.console import Console

from pbo_runtime.cli.exits import EXIT_OK


def clean(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.supervisor.cleanup import remove_dead_runs

    cleanup = remove_dead_runs(args.subsystem)
    removed = cleanup.removed
    console.print(f"removed {len(removed)} object(s) left by dead runs" + (": " + ", ".join(removed) if removed else ""),
                  markup=False)
    if cleanup.live:
        console.print(f"left {len(cleanup.live)} live run(s) alone: {', '.join(cleanup.live)} (pbo runs lists them)",
                      markup=False)
    if cleanup.ignored:
        console.print(f"ignored {len(cleanup.ignored)} object(s) named like a run's but not yours to trust "
                      f"(only uid {os.geteuid()}'s with mode 0600 are): {cleanup.ignored_summary()}; not touched: "
                      f"{', '.join(sorted(cleanup.ignored))}", markup=False)
    return EXIT_OK
