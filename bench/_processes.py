"""Worker processes that benchmarks start once and drive stretch by stretch over pipes.

Each worker runs `target(*args, conn)`: it sends "ready", then answers each command it receives
on `conn` until it receives None. The spawn start method gives every worker a fresh interpreter
(no threads or locks inherited from the benchmark runner).
"""

from __future__ import annotations

import contextlib
import multiprocessing
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any


class Workers:
    """n worker processes, started together and closed together (also on an error at start)."""

    def __init__(self, n: int, target: Callable[..., None], args: tuple[Any, ...] = (), what: str = "worker") -> None:
        self.what = what
        ctx = multiprocessing.get_context("spawn")
        self.procs: list[Any] = []
        self.pipes: list[Connection] = []
        try:
            for _ in range(n):
                here, there = ctx.Pipe()
                process = ctx.Process(target=target, args=(*args, there), daemon=True)
                process.start()
                self.procs.append(process)
                self.pipes.append(here)
            for here in self.pipes:
                if not here.poll(60) or here.recv() != "ready":
                    raise RuntimeError(f"a {what} process did not start within 60 s")
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> Workers:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def send_each(self, commands: list[Any]) -> None:
        """One command per worker, in order."""
        for here, command in zip(self.pipes, commands, strict=True):
            here.send(command)

    def answers(self, timeout: float) -> list[Any]:
        """Every worker's answer to its last command, waiting up to `timeout` for each."""
        answers = [here.recv() for here in self.pipes if here.poll(timeout)]
        if len(answers) != len(self.pipes):
            raise RuntimeError(f"{len(self.pipes) - len(answers)} of {len(self.pipes)} {self.what} processes did not report")
        return answers

    def close(self) -> None:
        for here in self.pipes:
            with contextlib.suppress(OSError):
                here.send(None)
        for process in self.procs:
            process.join(5)
            if process.is_alive():
                process.terminate()
                process.join(5)
        self.procs, self.pipes = [], []
