"""The parameter every subsystem interface module takes: which link of the application it serves."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LinkParams:
    link: str  # the link's name in the application file's `links:`

    def __post_init__(self) -> None:
        if not self.link:
            raise ValueError("link must name a link of the application file")
