"""One-way latency of a two-node 1 kHz exchange: through dora-rs, and through a periodic link of ours.

The exchange: one node sends a 6-float64 item (48 bytes), stamped with CLOCK_MONOTONIC, every
millisecond; another node, in another process, takes each item and records the time it got it
minus the stamp. Three ways, taking turns round by round:

- **dora-rs** (optional: `pip install dora-rs dora-rs-cli`, the `bench` extra): a dataflow of two
  Python nodes (bench/_dora_nodes.py) run by `dora run`: the source sends on each tick of dora's
  timer `dora/timer/millis/1`, the sink blocks in `node.next()` and stamps each item's arrival;
- **triple buffer**: the periodic link between two subsystems (`transport: shm`), the
  `TripleBuffer` link_sender and link_receiver open, written at 1 kHz by one process and polled
  every 20 µs by the other (bench/links.py's two processes: the same code measures it there);
- **zenoh**: the same link over `transport: zenoh` on tcp/127.0.0.1, its reader stamping each item
  as it arrives in its process (the "callback" delivery), as dora's sink does.

Lost: items sent but never seen by the receiving node. For a periodic link that is an item
overwritten before the reader took it (by design: the reader wants the newest); for dora, an item
dropped from the sink's input queue or never delivered. The benchmark is skipped, with the reason
printed, when dora-rs is not installed; the dora processes are stopped and their files removed
whatever happens.

    python -m bench.dora_peer [--seconds 5] [--rounds 3] [--schedulers fifo,other]
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Set as AbstractSet
from pathlib import Path
from typing import Any

import numpy as np

from bench._common import REPO, Section, Table, fmt_ratio, package_version, percentiles, ratio, us
from rtpu._realtime import FIFO_PRIORITY

PERIOD_NS = 1_000_000  # 1 kHz, both ways
POLL_NS = 50_000  # the triple buffer's reader polls this often (sleeping in between): it has no wake-up to wait on
ITEM_BYTES = 48  # 6 float64
WARMUP_ITEMS = 100  # the first 0.1 s of each dora run (nodes starting up) is left out, as links.py's warm-up is
STARTUP_PATIENCE = 60.0  # seconds `dora run` may take beyond the run's own before it is stopped
ZENOH_SEGMENT = re.compile(r"\d+\.zenoh")  # the shared memory of dora's zenoh session, in /dev/shm
NODES = Path(__file__).with_name("_dora_nodes.py")
PEERS = ("dora-rs", "triple buffer", "zenoh")
SCHEDULERS = ("fifo", "other")
LABELS = {"dora-rs": "dora-rs (Python nodes, `dora run`)", "triple buffer": "pbo link, transport shm (triple buffer)",
          "zenoh": "pbo link, transport zenoh"}
MEASURES = {"dora-rs": "arrival in the sink (blocked in `node.next()`)",
            "triple buffer": f"the reader's read that first got it (polls every {POLL_NS // 1000} µs)",
            "zenoh": "arrival in the reader's process (callback)"}
DATAFLOW = """\
nodes:
  - id: source
    path: {python}
    args: {nodes} source {work}/sent.txt {seconds}
    inputs:
      tick: dora/timer/millis/1
    outputs:
      - item
  - id: sink
    path: {python}
    args: {nodes} sink {work}/received.npy
    inputs:
      item: source/item
"""


def dora_command() -> str | None:
    """The `dora` program of dora-rs-cli beside this interpreter (or on PATH), when dora-rs is importable too."""
    if importlib.util.find_spec("dora") is None:
        return None
    beside = Path(sys.executable).with_name("dora")
    return str(beside) if beside.exists() else shutil.which("dora")


def missing() -> str:
    """Why dora-rs cannot be measured here, or "" when it can."""
    if dora_command() is None:
        return ("dora-rs not measured: dora-rs and dora-rs-cli are not installed "
                "(pip install -e '.[bench]', or pip install dora-rs dora-rs-cli)")
    return ""


def fifo_permitted() -> bool:
    """Whether this user may take SCHED_FIFO at an RTPU's priority (root, or a high enough `ulimit -r`)."""
    return os.geteuid() == 0 or resource.getrlimit(resource.RLIMIT_RTPRIO)[0] >= FIFO_PRIORITY


def _take_fifo() -> None:
    """SCHED_FIFO at an RTPU's priority, inherited by every process and thread started from here on."""
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))


# --- through dora ------------------------------------------------------------------------------


def _session(sid: int) -> list[int]:
    """The processes of session `sid`: `dora run` (started as its leader) and the nodes it spawned,
    each of which dora puts in a process group of its own."""
    members = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue  # gone meanwhile
        if int(fields[3]) == sid and fields[0] != "Z":  # fields after the name: state, ppid, pgrp, session
            members.append(int(entry))
    return members


def stop_session(process: subprocess.Popen) -> None:
    """Stop `dora run` and every node it started, whatever state they are in: SIGTERM, then SIGKILL."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        for pid in _session(process.pid):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, sig)
        give_up = time.monotonic() + 3.0
        while _session(process.pid) and time.monotonic() < give_up:
            process.poll()  # reaps `dora run`; the nodes are its children, reaped by it or by init
            time.sleep(0.02)
        if not _session(process.pid):
            break
    process.wait()


def orphan_segments(before: AbstractSet[str] = frozenset()) -> list[str]:
    """Shared-memory segments of a zenoh session (`<number>.zenoh`) made since `before` that no process maps."""
    made = [e for e in set(os.listdir("/dev/shm")) - before if ZENOH_SEGMENT.fullmatch(e)]
    if not made:
        return []
    mapped = set()
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/maps") as f:
                    mapped |= {line.rsplit("/", 1)[-1].strip() for line in f if "/dev/shm/" in line}
            except OSError:
                continue
    return [e for e in made if e not in mapped]


def remove_orphan_segments(before: AbstractSet[str]) -> list[str]:
    """Remove the segments dora's own zenoh session made since `before` and left behind: dora removes
    them when it ends, not when it is killed."""
    removed = orphan_segments(before)
    for entry in removed:
        Path("/dev/shm", entry).unlink(missing_ok=True)
    return removed


def dora_round(seconds: float, patience: float = STARTUP_PATIENCE, fifo: bool = False) -> dict[str, Any]:
    """One `dora run` of the two nodes for `seconds`: sent count and the sink's (sequence, latency ns).

    `fifo`: `dora run`, its daemon's threads and the nodes it starts all at SCHED_FIFO (inherited).
    """
    command = dora_command()
    if command is None:
        raise RuntimeError(missing())
    shm_before = set(os.listdir("/dev/shm"))
    try:
        with tempfile.TemporaryDirectory(prefix="pbo-bench-dora-") as work:
            dataflow = Path(work) / "dataflow.yml"
            dataflow.write_text(DATAFLOW.format(python=sys.executable, nodes=NODES, work=work, seconds=seconds))
            with open(Path(work) / "dora.log", "wb") as log:
                argv = [command, "run", str(dataflow)]
                if fifo:  # through exec, not preexec_fn (unsafe once the runner has threads): same process, same session
                    argv = [sys.executable, "-c", f"import os, sys; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param("
                            f"{FIFO_PRIORITY})); os.execv(sys.argv[1], sys.argv[1:])", *argv]
                process = subprocess.Popen(argv, cwd=work, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                           start_new_session=True)
                try:
                    try:
                        status = process.wait(seconds + patience)
                    except subprocess.TimeoutExpired:
                        raise RuntimeError(f"`dora run` did not finish within {seconds + patience:.0f} s") from None
                finally:
                    stop_session(process)  # after a normal end there is nothing left to stop; after a failure, everything
            sent_file, received_file = Path(work) / "sent.txt", Path(work) / "received.npy"
            if status != 0 or not sent_file.exists() or not received_file.exists():
                tail = (Path(work) / "dora.log").read_text(errors="replace").strip().splitlines()[-3:]
                raise RuntimeError(f"`dora run` exited with {status}: " + " / ".join(tail))
            sent = int(sent_file.read_text())
            seqs, latencies = np.load(received_file)
    finally:
        remove_orphan_segments(shm_before)
    kept = seqs > WARMUP_ITEMS
    return {"due": max(0, int(seconds * 1e9 / PERIOD_NS) - WARMUP_ITEMS), "sent": max(0, sent - WARMUP_ITEMS),
            "seen": int(np.unique(seqs[kept]).size), "latency_ns": latencies[kept]}


# --- through our links -------------------------------------------------------------------------


def link_round(mechanism: str, seconds: float, fifo: bool = False) -> dict[str, Any]:
    """bench/links.py's two processes at 1 kHz, in a fresh interpreter (they fork; the runner has threads)."""
    items = max(1, int(seconds * 1e9 / PERIOD_NS))
    code = ("import json, sys; from bench.dora_peer import _link_round_here; "
            f"print(json.dumps(_link_round_here({mechanism!r}, {items}, {fifo!r})))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=seconds * 3 + 120, cwd=REPO)
    if done.returncode != 0:
        raise RuntimeError(f"{mechanism}: " + " / ".join(done.stderr.strip().splitlines()[-2:]))
    answer = json.loads(done.stdout.strip().splitlines()[-1])
    return {"due": items, "sent": answer["sent"], "seen": answer["seen"],
            "latency_ns": np.asarray(answer["latency_ns"], dtype=np.int64)}


def _link_round_here(mechanism: str, items: int, fifo: bool) -> dict[str, Any]:
    from bench import links

    if fifo:
        _take_fifo()  # the two processes links.measure forks inherit it

    contender = "zenoh callback" if mechanism == "zenoh" else mechanism
    results = links.measure(contender, ITEM_BYTES, items, (PERIOD_NS, POLL_NS), sleep=True)
    _samples, sent, _ = results["write"]
    _samples, seen, ages = results["read"]
    assert ages is not None, f"{contender}: a link that stamps its items gives their ages"
    column = 1 if mechanism == "zenoh" else 0  # zenoh: arrival in the process; triple buffer: the read that got it
    return {"sent": int(sent), "seen": int(seen), "latency_ns": [int(a) for a in ages[:, column]]}


# --- the benchmark -----------------------------------------------------------------------------


def run(seconds: float = 5.0, rounds: int = 3, schedulers: tuple[str, ...] = SCHEDULERS) -> Section:
    """Each way for `seconds` per round and scheduler, in `rounds` rounds of rotating order; samples pooled."""
    section = Section(
        key="dora",
        title="Against dora-rs: a two-node 1 kHz exchange, one-way latency and lost items",
        command=f"python -m bench.dora_peer --seconds {seconds:g} --rounds {rounds} --schedulers {','.join(schedulers)}",
        method=f"""
One node sends a 6-float64 item (48 bytes) stamped with CLOCK_MONOTONIC every millisecond; another
process receives it, and the latency is the time it got the item minus the stamp (one clock, one
machine). **dora-rs**: a dataflow of two Python nodes run by `dora run` (its daemon inside the
`dora` process, no coordinator): the source sends a pyarrow array on each tick of dora's 1 ms
timer, stamped just before `send_output`; the sink blocks in `node.next()` and stamps each item as
it returns. **pbo link**: the two ends of a periodic link between two subsystems, the same
`TripleBuffer` (`transport: shm`) or `ZenohLink` (`transport: zenoh`, tcp/127.0.0.1) that
`link_sender` and `link_receiver` open, in bench/links.py's two processes, each sleeping to its
next release as an RTPU does: the sender writes every 1 ms (the link stamps the item as `write`
is called); the triple buffer's receiver polls every {POLL_NS // 1000} µs, since a triple buffer wakes
nobody (an item waits up to {POLL_NS // 1000} µs for the poll), and the zenoh receiver is stamped as
the item arrives in its process, as dora's sink is. A `link_receiver` task reads only at its
release, so in a running subsystem an item also waits for that task's next cycle (0 to 1 period):
that wait is the same whatever carries the item, and is left out on both sides.

**Lost**: items sent and never seen by the receiver. For a periodic link (either transport) an
item overwritten before the reader took it counts as lost (the link keeps only the newest, by design: a late
sender catches up and a late reader skips); for dora, an item dropped or never delivered (its
sink queues items, so a late sink catches up instead). dora's timer skips the ticks it could not
deliver on time, so under load its source sends fewer items: lost % is of the items each sent,
and **seen of 1 kHz %** is of the items a 1 kHz schedule was due to send over the same seconds
(what the receiver got, whichever side of the exchange fell behind).

Each side runs under the same scheduler: **fifo**, every process of both (dora's daemon and
nodes included) at SCHED_FIFO {FIFO_PRIORITY}, the priority of an RTPU, which is how a subsystem's tasks run
by default; **other**, all at SCHED_OTHER, sharing the CPUs with everything else. {seconds:g} s per
way per round and scheduler, {rounds} round(s) in rotating order; dora's first {WARMUP_ITEMS} items
of each run (its nodes starting) are left out. Ratios are pbo / dora-rs, same scheduler.
""",
        limits="""Python on both sides: dora's nodes pay pyarrow conversion and its Rust
daemon's hops (source to daemon to sink over local sockets), our link a Python `write` and
`read`. Under SCHED_OTHER on this shared 2-vCPU VM, a poller that wakes every 50 µs is the first
to lose its CPU when other tenants are busy (the scheduler favours a sleeper that wakes once per
item), which is where most of the triple buffer's lost items come from; under SCHED_FIFO the
p99 column mostly measures the hypervisor.""",
    )
    reason = missing()
    if reason:
        section.notes.append(reason)
        return section
    if "fifo" in schedulers and not fifo_permitted():
        schedulers = tuple(k for k in schedulers if k != "fifo")
        section.notes.append(f"fifo: not measured: SCHED_FIFO {FIFO_PRIORITY} needs root "
                             "or a real-time priority limit (ulimit -r)")
        if not schedulers:
            return section
    pooled: dict[tuple[str, str], list[dict[str, Any]]] = {}
    failed: dict[tuple[str, str], str] = {}
    for turn in range(rounds):
        for scheduler in schedulers:
            for peer in PEERS[turn % len(PEERS):] + PEERS[: turn % len(PEERS)]:
                key = (scheduler, peer)
                if key in failed:
                    continue
                fifo = scheduler == "fifo"
                try:
                    result = dora_round(seconds, fifo=fifo) if peer == "dora-rs" else link_round(peer, seconds, fifo=fifo)
                except Exception as exc:  # a way that fails is reported in its row, never a crash
                    failed[key] = f"failed: {str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__}"
                    continue
                pooled.setdefault(key, []).append(result)
    table = Table(["scheduler", "way", "time taken at", "sent", "lost", "lost %", "seen of 1 kHz %", "p50 µs", "p99 µs", "max µs",
                   "p50 / dora", "p99 / dora"], numeric=(3, 4, 5, 6, 7, 8, 9, 10, 11),
                  caption=f"dora-rs {package_version('dora-rs')}; one-way latency at 1 kHz, 48-byte items")
    for scheduler in schedulers:
        figures = {peer: _figures(pooled[scheduler, peer]) for peer in PEERS if (scheduler, peer) in pooled}
        dora = figures.get("dora-rs")
        for peer in PEERS:
            if (scheduler, peer) in failed or peer not in figures:
                table.add(scheduler, LABELS[peer], MEASURES[peer], failed.get((scheduler, peer), "failed"), "",
                          "", "", "", "", "", "", "")
                continue
            f = figures[peer]
            r50 = ratio(f["p50"], dora["p50"]) if dora else None
            r99 = ratio(f["p99"], dora["p99"]) if dora else None
            if peer != "dora-rs":
                for q, value in (("p50", r50), ("p99", r99)):
                    if value is not None:
                        section.ratios[f"{peer} / dora-rs one-way {q} ({scheduler})"] = value
            table.add(scheduler, LABELS[peer], MEASURES[peer], f"{int(f['sent']):,}", f"{int(f['lost']):,}",
                      f"{100 * f['lost'] / f['sent']:.2f}" if f["sent"] else "n/a",
                      f"{100 * f['seen'] / f['due']:.1f}" if f["due"] else "n/a", us(f["p50"], ns=True), us(f["p99"], ns=True),
                      us(f["max"], ns=True), "1.00x" if peer == "dora-rs" else fmt_ratio(r50),
                      "1.00x" if peer == "dora-rs" else fmt_ratio(r99))
        if dora and "triple buffer" in figures:
            shm = figures["triple buffer"]
            section.notes.append(
                f"{scheduler}: one-way, pbo shm link / dora-rs: p50 {fmt_ratio(ratio(shm['p50'], dora['p50']))}, p99 "
                f"{fmt_ratio(ratio(shm['p99'], dora['p99']))}; lost {shm['lost'] / shm['sent']:.2%} of {int(shm['sent']):,} "
                f"against {dora['lost'] / dora['sent']:.2%} of {int(dora['sent']):,}" if shm["sent"] and dora["sent"] else
                f"{scheduler}: nothing sent")
    section.tables.append(table)
    section.notes.append("No goal is set for these figures (issue 23 asks for them side by side): they are reported, not judged.")
    return section


def _figures(results: list[dict[str, Any]]) -> dict[str, float]:
    latency = np.concatenate([r["latency_ns"] for r in results])
    sent, seen = sum(r["sent"] for r in results), sum(r["seen"] for r in results)
    p50, p99 = percentiles(latency)
    return {"due": sum(r["due"] for r in results), "sent": sent, "seen": seen,
            "lost": max(0, sent - seen), "p50": p50, "p99": p99,
            "max": float(latency.max()) if latency.size else float("nan")}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=5.0, help="seconds per way per round")
    parser.add_argument("--rounds", type=int, default=3, help="rounds, the ways taking turns in rotating order")
    parser.add_argument("--schedulers", default=",".join(SCHEDULERS), help="fifo, other, or both (comma-separated)")
    args = parser.parse_args(argv)
    schedulers = tuple(k for k in args.schedulers.split(",") if k)
    if not schedulers or set(schedulers) - set(SCHEDULERS):
        parser.error(f"--schedulers: choose from {', '.join(SCHEDULERS)}")
    print(run(args.seconds, args.rounds, schedulers).text())


if __name__ == "__main__":
    main()
