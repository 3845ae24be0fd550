"""What a configuration file is, and how every process of a run loads it, known before it is loaded.

Kept apart from the loader so the CLI can start a run's fork server before it imports numpy and
the checker (`pbo run`: the server's imports then overlap the CLI's own).
"""

from __future__ import annotations

import os

from pbo_runtime.config.limits import MAX_FILE_BYTES

# Set to "1" for every process of a run by `pbo run --allow-unstable-loops`: the loader waives E326
ALLOW_UNSTABLE_LOOPS = "PBO_ALLOW_UNSTABLE_LOOPS"


def is_application_file(path: str | os.PathLike[str]) -> bool:
    """True if the file's first top-level key is `application:` (a subsystem file starts otherwise)."""
    try:
        # undecodable bytes and a file too large are the loader's to report: here they only must not raise
        if os.path.getsize(path) > MAX_FILE_BYTES:
            return False
        with open(path, encoding="utf-8", errors="replace") as text:
            for line in text:
                stripped = line.strip()
                if stripped and not stripped.startswith("#") and not line[0].isspace():
                    return stripped.startswith("application:")
    except OSError:
        return False
    return False
