"""An application's link as its runner made it for one run: what a task needs to open an end.

The application runner (`supervisor.application_runner`) makes one per link before the subsystems
start; it travels as JSON on the command lines (`pbo run --links`, then each RTPU's `--links`) and
into report.json, and `links.ends.open_link_end` opens an end of it:

    {"kind": "periodic", "transport": "shm", "dtype": "float64", "shape": [6], "object": "/pbo.<app>.<run id>.link-<name>"}
    {"kind": "message", "transport": "shm", ..., "capacity": 8, "object": "/pbo.<app>.<run id>.msg-<name>"}
    {"kind": "periodic", "transport": "zenoh", ..., "key": "pbo/<app>/<name>", "endpoint": "tcp/127.0.0.1:<port>"}
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class RunLink:
    """One link of the run: its kind and transport, its item's type and shape, and where it is."""

    kind: str  # "periodic" or "message"
    transport: str  # "shm" or "zenoh" (links.spec.TRANSPORTS)
    dtype: str
    shape: tuple[int, ...]
    capacity: int | None = None  # a message link: messages queued at most
    key: str = ""  # zenoh: the key both ends agree on
    endpoint: str = ""  # zenoh: where the listening end listens, "tcp/<host>:<port>"
    shm_name: str = ""  # shm: the POSIX object the runner made ("object" in JSON)
    wait: float | None = None  # zenoh: seconds an attaching end waits for its peer (None: the transport's own)

    def to_json(self) -> dict[str, object]:
        entry: dict[str, object] = {"kind": self.kind, "transport": self.transport, "dtype": self.dtype,
                                    "shape": list(self.shape)}
        if self.kind == "message":
            entry["capacity"] = self.capacity
        if self.transport == "zenoh":
            entry.update(key=self.key, endpoint=self.endpoint)
        else:
            entry["object"] = self.shm_name
        if self.wait is not None:
            entry["wait"] = self.wait
        return entry

    @classmethod
    def from_json(cls, entry: Mapping[str, object]) -> RunLink:
        shape, capacity, wait = entry.get("shape", []), entry.get("capacity"), entry.get("wait")
        return cls(str(entry.get("kind", "periodic")), str(entry.get("transport", "shm")), str(entry.get("dtype", "")),
                   tuple(int(n) for n in shape if isinstance(n, int)) if isinstance(shape, list) else (),
                   capacity if isinstance(capacity, int) else None, str(entry.get("key", "")),
                   str(entry.get("endpoint", "")), str(entry.get("object", "")),
                   float(wait) if isinstance(wait, int | float) else None)


def links_to_json(links: Mapping[str, RunLink]) -> str:
    """The run's links as the command lines carry them."""
    return json.dumps({name: link.to_json() for name, link in links.items()})


def links_from_json(text: str) -> dict[str, RunLink]:
    """The run's links from a command line's JSON (`links_to_json`)."""
    given = json.loads(text) if text else {}
    if not isinstance(given, dict):
        raise ValueError(f"--links takes a JSON object of links by name, got: {text[:80]}")
    return {str(name): RunLink.from_json(entry) for name, entry in given.items() if isinstance(entry, dict)}
