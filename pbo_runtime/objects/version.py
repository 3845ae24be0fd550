"""pbo-runtime's installed version, read without importing the package metadata library or typing:
`pbo --version` imports this module and nothing else of the runtime."""

from __future__ import annotations

import functools
import os
import sys


@functools.cache  # read once per process: a forked RTPU has it from its fork server
def installed_version() -> str:
    """pbo-runtime's version as installed (pyproject.toml's): the one source of `pbo --version`.

    Read from the installed distribution's METADATA file where it is found on sys.path, as
    importlib.metadata would: importing that alone costs `pbo --version` most of its time."""
    found = _version_in_metadata_file()
    if found is not None:
        return found
    from importlib import metadata

    try:
        return metadata.version("pbo-runtime")
    except metadata.PackageNotFoundError:  # a checkout imported without installing it
        return "0+unknown"


def _version_in_metadata_file() -> str | None:
    """The Version: of the first `pbo_runtime-*.dist-info` on sys.path (None: none there, or unreadable)."""
    for folder in sys.path:
        try:
            names = os.listdir(folder or ".")
        except OSError:
            continue
        for name in names:
            if name.startswith("pbo_runtime-") and name.endswith(".dist-info"):
                try:
                    with open(os.path.join(folder or ".", name, "METADATA"), encoding="utf-8") as file:
                        for line in file:
                            if line.startswith("Version:"):
                                return line.partition(":")[2].strip()
                            if not line.strip():
                                break  # the headers end at the first blank line
                except OSError:
                    pass
    return None
