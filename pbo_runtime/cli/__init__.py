"""The `pbo` command."""

from pbo_runtime.cli.main import main

__all__ = ["main"]
