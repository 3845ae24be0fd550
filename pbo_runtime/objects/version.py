"""pbo-runtime's installed version, read without importing the package metadata library or typing:
`pbo --version` imports this module and `objects.distributions`, nothing else of the runtime."""

from __future__ import annotations

import functools

from pbo_runtime.objects import distributions


@functools.cache  # read once per process: a forked RTPU has it from its fork server
def installed_version() -> str:
    """pbo-runtime's version as installed (pyproject.toml's): the one source of `pbo --version`.

    Read from the installed distribution's METADATA file on sys.path (`distributions`), as
    importlib.metadata would: importing that alone costs `pbo --version` most of its time."""
    return distributions.version("pbo-runtime") or "0+unknown"  # (unknown: a checkout imported without installing it)
