"""What an RTPU process is started with: one typed description, built by the supervisor, read by `rtpu`.

The supervisor builds an `RtpuLaunch`, hands it to the child on its command line (`to_argv`: what
`ps` shows stays readable, and a fork server passes it on unchanged), and `python -m rtpu` reads it
back (`RtpuLaunch.parse`). A restart launches the same description with a field changed
(`dataclasses.replace`), never by editing the argument list.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from dataclasses import dataclass, field

from pbo_runtime.config.model import DEFAULT_SPIN
from pbo_runtime.links.run_link import RunLink, links_from_json, links_to_json

SIM_TICK_DEFAULT = 0.001  # seconds per tick when none is given (the real clock has no tick)


@dataclass(frozen=True)
class RtpuLaunch:
    """One RTPU process of a run: which file, run and RTPU, its clock, and what it continues from."""

    file: str
    run_id: str
    rtpu: str
    epoch: float = 0.0  # CLOCK_MONOTONIC time its releases align to
    spin: float = DEFAULT_SPIN  # seconds spun before each release
    fifo: bool = False  # ask for SCHED_FIFO (reported if refused)
    clock: str = "real"  # "real", or "sim": advance in the supervisor's ticks
    tick: float = SIM_TICK_DEFAULT  # seconds per tick of the simulated clock
    ring: tuple[str, ...] = ()  # sim: the participants of a tick, in order (clock.lockstep)
    out: str = ""  # directory the modules write their files into
    configuration: str = ""  # the configuration the run started in (for the logs' metadata)
    application: str = ""  # the application the run runs (for the logs' metadata)
    links: Mapping[str, RunLink] = field(default_factory=dict)  # the application's links, by name
    live: str = ""  # directory of the run's live descriptions (live-N.json)
    live_now: int = 0  # a restart after live changes: live-N.json describes the run, not the file (0: the file)
    restarted: bool = False  # a restart after this RTPU's process died: its tasks continue the run's files
    parent: int = 0  # the supervisor's pid (added by whoever starts the process)

    def to_argv(self) -> list[str]:
        """The command line after `python -m rtpu` (`parse` reads it back)."""
        argv = [self.file, "--run-id", self.run_id, "--rtpu", self.rtpu, "--epoch", repr(self.epoch),
                "--spin", repr(self.spin)]
        if self.fifo:
            argv.append("--fifo")
        if self.clock != "real":
            argv += ["--clock", self.clock, "--tick", repr(self.tick), "--ring", ",".join(self.ring)]
        if self.out:
            argv += ["--out", self.out]
        argv += ["--configuration", self.configuration, "--application", self.application]
        if self.links:
            argv += ["--links", links_to_json(self.links)]
        argv += ["--live", self.live]
        if self.restarted:
            argv.append("--restarted")
        if self.live_now:
            argv += ["--live-now", str(self.live_now)]
        if self.parent:
            argv += ["--parent", str(self.parent)]
        return argv

    @classmethod
    def parse(cls, argv: list[str] | None, description: str | None = None) -> RtpuLaunch:
        """Read `python -m rtpu`'s command line (argparse exits with a usage message if it is wrong)."""
        args = _parser(description).parse_args(argv)
        return cls(file=args.file, run_id=args.run_id, rtpu=args.rtpu, epoch=args.epoch, spin=args.spin,
                   fifo=args.fifo, clock=args.clock, tick=args.tick,
                   ring=tuple(args.ring.split(",")) if args.ring else (), out=args.out,
                   configuration=args.configuration, application=args.application, links=links_from_json(args.links),
                   live=args.live, live_now=args.live_now, restarted=args.restarted, parent=args.parent)


def _parser(description: str | None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m rtpu", description=description)
    parser.add_argument("file")
    parser.add_argument("--run-id", required=True)
    parser.add_argument("--rtpu", required=True)
    parser.add_argument("--epoch", type=float, default=0.0, help="CLOCK_MONOTONIC time releases align to")
    parser.add_argument("--parent", type=int, default=0)
    parser.add_argument("--spin", type=float, default=DEFAULT_SPIN, help="seconds spun before each release")
    parser.add_argument("--fifo", action="store_true", help="ask for SCHED_FIFO (reported if refused)")
    parser.add_argument("--clock", choices=("real", "sim"), default="real", help="sim: advance in the supervisor's ticks")
    parser.add_argument("--tick", type=float, default=SIM_TICK_DEFAULT, help="seconds per tick of the simulated clock")
    parser.add_argument("--ring", default="", help="sim: the participants of a tick, in order (clock.lockstep)")
    parser.add_argument("--out", default="", help="directory the modules write their files into")
    parser.add_argument("--configuration", default="", help="the configuration the run started in (for the logs' metadata)")
    parser.add_argument("--application", default="", help="the application the run runs (for the logs' metadata)")
    parser.add_argument("--links", default="{}", help="JSON: the application's links, by name")
    parser.add_argument("--restarted", action="store_true",
                        help="a restart after this RTPU's process died: its tasks continue the run's files (restart policy)")
    parser.add_argument("--live", default="", help="directory of the run's live descriptions (live-N.json, `LiveUpdate`)")
    parser.add_argument("--live-now", type=int, default=0, metavar="N",
                        help="a restart after live changes: live-N.json describes the run from the start, not the file")
    return parser
