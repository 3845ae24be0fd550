"""`pbo plot RUN` and `pbo log export|info RUN`: a run's data logs, drawn or handed to other tools."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from rich.console import Console

from pbo_runtime.cli.exits import EXIT_CONFIG, EXIT_OK
from pbo_runtime.errors import require_extra


def plot(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.reports.data_log import LogError
    from pbo_runtime.reports.run_plot import figure, load_run, plot_axes, save

    require_extra("matplotlib", "pbo plot")
    try:
        run = load_run(args.target)
        plot_axes(run, args.variables)  # an unknown variable is refused before anything is drawn
        if args.output is None and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            raise LogError("no display to show the plot on: write it to a file with -o plot.png (or .svg)")
        if args.output is not None:
            save(figure(run, args.variables), args.output)
            console.print(f"wrote {args.output}", markup=False)
            return EXIT_OK
    except (LogError, OSError) as exc:
        errors.print(f"error: {exc}", markup=False)
        return EXIT_CONFIG
    import matplotlib.pyplot as plt

    figure(run, args.variables, new=plt.figure)  # the same figure, in a window of the interactive backend
    plt.show()
    return EXIT_OK


def export(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.reports.data_log import LogError, open_log
    from pbo_runtime.reports.run_plot import csv_text, logs_to_export

    try:
        logs = logs_to_export(Path(args.log), args.output)
        if args.output is None:
            sys.stdout.write(csv_text(open_log(logs[0])))
            return EXIT_OK
        for log in logs:
            output = args.output / f"{log.stem}.csv" if len(logs) > 1 else args.output
            text = csv_text(open_log(log))
            output.write_text(text)
            console.print(f"wrote {output} ({text.count(chr(10)) - 1} rows)", markup=False)
    except (LogError, OSError) as exc:
        errors.print(f"error: {exc}", markup=False)
        return EXIT_CONFIG
    return EXIT_OK


def info(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.reports.data_log import LogError
    from pbo_runtime.reports.log_info import infos, text

    try:
        found = infos(Path(args.log))
    except (LogError, OSError) as exc:
        errors.print(f"error: {exc}", markup=False)
        return EXIT_CONFIG
    console.out("\n\n".join(text(log) for log in found), highlight=False)
    return EXIT_OK
