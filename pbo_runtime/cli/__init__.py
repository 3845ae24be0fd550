"""The `pbo` command.

`pbo --version` answers before the command's modules load (numpy, the checker, the runtime): a
terminal's question gets a terminal's answer time.
"""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    if (sys.argv[1:] if argv is None else argv) == ["--version"]:
        from pbo_runtime.objects.registry import installed_version

        print(f"pbo {installed_version()}")
        raise SystemExit(0)  # as argparse's version action ends
    from pbo_runtime.cli.main import main as run_command

    return run_command(argv)


__all__ = ["main"]
