"""What names a link in a file and in the spec handed down: its transports and a zenoh endpoint.

A leaf: the application checker (config) and every link end (links) read it, and it imports nothing
of the runtime, so the transports are listed once.
"""

from __future__ import annotations

import re
from typing import Any

TRANSPORTS = ("shm", "zenoh")
_TCP_ENDPOINT = re.compile(r"^tcp/(?P<host>[^/:\s]+):(?P<port>\d{1,5})$")


def parse_endpoint(text: Any) -> tuple[str, int] | None:
    """(host, port) of a zenoh endpoint written `tcp/<host>:<port>`, or None if it is not one."""
    found = _TCP_ENDPOINT.match(str(text))
    if found is None or not 0 < int(found["port"]) < 65536:
        return None
    return found["host"], int(found["port"])
