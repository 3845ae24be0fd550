"""`pbo hmi`: the local API and the browser HMI for a live run (`api.server`), or for an application file's stages."""

from __future__ import annotations

import argparse
import contextlib
import os

from rich.console import Console

from pbo_runtime.cli.exits import EXIT_CONFIG, EXIT_OK
from pbo_runtime.errors import require_extra


def serve_api(args: argparse.Namespace, console: Console, errors: Console) -> int:
    if args.file is not None and not os.path.isfile(args.file):
        errors.print(f"error: no subsystem file '{args.file}': give the YAML file of the subsystem (or of an application), "
                     "or none", markup=False)
        return EXIT_CONFIG
    if not 0 <= args.port <= 65535:
        errors.print(f"error: --port must be 0 to 65535, got: {args.port}", markup=False)
        return EXIT_CONFIG
    for module in ("fastapi", "uvicorn", "websockets"):
        require_extra(module, "pbo hmi")
    from pbo_runtime.api.server import serve

    def say(text: str) -> None:
        console.print(text, markup=False, soft_wrap=True)  # the URL stays on one line
        console.file.flush()  # at once, when a script reads the URL from a pipe

    def warn(text: str) -> None:
        errors.print(text, markup=False)
        errors.file.flush()

    with contextlib.suppress(KeyboardInterrupt):
        return serve(os.path.abspath(args.file) if args.file else None, args.host, args.port, args.subsystem, args.run,
                     say, warn, args.allow_remote)
    return EXIT_OK
