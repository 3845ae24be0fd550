"""Send and receive latency of a message link between two processes: the POSIX queue against zenoh.

A sender process sends small messages (a dict of six floats, priorities 0..3) every
SENDER_PERIOD_NS with `send(body, priority, timeout=0)`; a receiver process takes them one of
two ways, each side sleeping to its releases as an RTPU does:

- "cycle": `receive(timeout=0)` every READER_PERIOD_NS, taking every waiting message, as a task's
  cycle would (a call that finds nothing is timed apart: "receive (empty)");
- "waiting": `receive()` without a timeout in a loop, as the relay thread of a server task does
  (only its one-way latency is kept: the call lasts until a message comes).

Every call is timed (`perf_counter_ns`); one-way is from the message's `sent_ns` to the return of
the `receive` that took it (CLOCK_MONOTONIC on both sides). Ratios are to the POSIX queue's same
mode and side, measured in the same run; the contenders take turns round by round.

    python -m bench.message_links [--quick] [--messages N] [--rounds R]
"""

from __future__ import annotations

import argparse
import importlib.util
import multiprocessing
import os
import time

import numpy as np

from pbo_runtime.clock.clocks import lower_timer_slack
from pbo_runtime.links.message_link import LinkFullError, MessageLink
from pbo_runtime.links.zenoh_session import free_port

MESSAGES, QUICK_MESSAGES = 4_000, 400
ROUNDS = 3  # turns the contenders take (--quick: 1)
SENDER_PERIOD_NS = 500_000
READER_PERIOD_NS = 325_000  # 0.65 of the sender's: the two drift through every phase
END = "end"  # the sender's last message (priority 0: after everything it sent)
ZENOH = importlib.util.find_spec("zenoh") is not None  # found, not imported: children open sessions after the fork
CONTENDERS = ("posix queue",) + (("zenoh",) if ZENOH else ())
MODES = ("cycle", "waiting")
SIDES = ("send", "receive", "receive (empty)", "one-way")
FORK = multiprocessing.get_context("fork")


def _open(contender: str, where: tuple[str, int], receiving: bool):
    name, port = where
    if contender == "posix queue":
        return MessageLink.create(name, capacity=10) if receiving else MessageLink.attach(name)
    from pbo_runtime.links.zenoh_message_link import ZenohMessageLink

    key = name.strip("/").replace(".", "/")
    return ZenohMessageLink.create(key, capacity=10, port=port) if receiving else ZenohMessageLink.attach(key, port=port)


def _doze(release: int) -> None:
    delay = release - time.perf_counter_ns()
    if delay > 0:
        time.sleep(delay / 1e9)


def _sender(contender: str, where: tuple[str, int], count: int, listening, results) -> None:
    lower_timer_slack()
    listening.wait(30)
    link = _open(contender, where, receiving=False)
    body = {"goal": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6], "i": 0}
    samples = np.empty(count, dtype=np.int64)
    refused = 0
    clock, send = time.perf_counter_ns, link.send
    release = clock()
    for i in range(count):
        _doze(release)
        body["i"] = i
        t0 = clock()
        try:
            send(body, i % 4, 0.0)
        except LinkFullError:
            refused += 1
        samples[i] = clock() - t0
        release = max(release + SENDER_PERIOD_NS, t0)
    link.send(END, 0, 5.0)
    results.send({"send": samples, "refused": refused})
    time.sleep(0.2)  # stay until the receiver has taken the last message (zenoh: still in flight)
    link.close()


def _receiver(contender: str, where: tuple[str, int], count: int, mode: str, listening, results) -> None:
    lower_timer_slack()
    link = _open(contender, where, receiving=True)
    listening.set()
    got, empty = np.empty(count + 1, dtype=np.int64), np.empty(count * 4, dtype=np.int64)
    one_way = np.empty(count + 1, dtype=np.int64)
    n_got = n_empty = 0
    clock, now, receive = time.perf_counter_ns, time.monotonic_ns, link.receive
    timeout = 0.0 if mode == "cycle" else None
    release = clock()
    done = False
    while not done:
        if mode == "cycle":
            _doze(release)
            release = max(release + READER_PERIOD_NS, clock())
        while True:
            t0 = clock()
            message = receive(timeout)
            t1 = clock()
            if message is None:
                if n_empty < empty.size:
                    empty[n_empty] = t1 - t0
                    n_empty += 1
                break
            one_way[n_got], got[n_got] = now() - message.sent_ns, t1 - t0
            n_got += 1
            if message.body == END or n_got > count:
                done = True
                break
    results.send({"receive": got[: n_got - 1], "receive (empty)": empty[:n_empty], "one-way": one_way[: n_got - 1]})
    link.close()


def measure(contender: str, mode: str, count: int) -> dict[str, np.ndarray | int]:
    """{side: call or one-way latencies in ns, "refused": sends refused} of one contender and mode."""
    where = (f"/pbo.bench.{os.getpid()}-{os.urandom(3).hex()}.msg", free_port())
    listening = FORK.Event()
    pipes = {side: FORK.Pipe(duplex=False) for side in ("send", "receive")}
    children = [FORK.Process(target=_receiver, args=(contender, where, count, mode, listening, pipes["receive"][1])),
                FORK.Process(target=_sender, args=(contender, where, count, listening, pipes["send"][1]))]
    try:
        for child in children:
            child.start()
        figures: dict[str, np.ndarray | int] = {}
        for side in ("send", "receive"):
            if not pipes[side][0].poll(120):
                raise RuntimeError(f"message link bench: the {side} side of {contender} ({mode}) did not finish")
            figures.update(pipes[side][0].recv())
        return figures
    finally:
        for child in children:
            child.join(30)
            if child.is_alive():
                child.terminate()


def run(quick: bool = False, messages: int | None = None, rounds: int | None = None) -> list[dict]:
    """One row per contender, mode and side: latencies in µs and ratios to the POSIX queue's."""
    rounds = rounds or (1 if quick else ROUNDS)
    per_round = -(-(messages or (QUICK_MESSAGES if quick else MESSAGES)) // rounds)
    pooled: dict[tuple[str, str, str], list[np.ndarray]] = {}
    refused: dict[tuple[str, str], int] = {}
    for turn in range(rounds):
        for mode in MODES:
            for contender in CONTENDERS[turn % len(CONTENDERS):] + CONTENDERS[: turn % len(CONTENDERS)]:
                figures = measure(contender, mode, per_round)
                refused[contender, mode] = refused.get((contender, mode), 0) + int(figures.pop("refused"))
                for side, samples in figures.items():
                    pooled.setdefault((contender, mode, side), []).append(np.asarray(samples))
    stats = {}
    for key, parts in pooled.items():
        samples = np.concatenate(parts)
        if samples.size:
            p50, p99 = np.percentile(samples, [50, 99]) / 1000
            stats[key] = (samples.size, float(p50), float(p99), float(samples.max() / 1000))
    rows = []
    for mode in MODES:
        for contender in CONTENDERS:
            for side in SIDES:
                if (contender, mode, side) not in stats or (mode == "waiting" and side.startswith("receive")):
                    continue
                calls, p50, p99, worst = stats[contender, mode, side]
                base = stats.get(("posix queue", mode, side), (0, p50, p99, worst))
                rows.append({"mechanism": contender, "mode": mode, "side": side, "calls": calls, "p50_us": p50,
                             "p99_us": p99, "max_us": worst, "p50_ratio": p50 / base[1], "p99_ratio": p99 / base[2],
                             "refused": refused[contender, mode]})
    return rows


def table(rows: list[dict]) -> str:
    headers = ("mode", "mechanism", "side", "calls", "p50 µs", "p99 µs", "max µs", "p50 x", "p99 x", "refused")
    body = [(r["mode"], r["mechanism"], r["side"], str(r["calls"]), f"{r['p50_us']:.1f}", f"{r['p99_us']:.1f}",
             f"{r['max_us']:.0f}", f"{r['p50_ratio']:.2f}", f"{r['p99_ratio']:.2f}", str(r["refused"])) for r in rows]
    widths = [max(len(h), *(len(b[i]) for b in body)) for i, h in enumerate(headers)]
    fmt = "  ".join(f"{{:{'<' if i < 3 else '>'}{w}}}" for i, w in enumerate(widths))
    lines = [f"Message link between two processes ({os.cpu_count()} CPUs); x = ratio to the POSIX queue, same mode and side",
             fmt.format(*headers), fmt.format(*("-" * w for w in widths)), *(fmt.format(*b) for b in body)]
    if not ZENOH:
        lines.append("zenoh: not measured: eclipse-zenoh is not installed (pip install 'eclipse-zenoh>=1.0')")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="small counts: a check that it runs, not a measurement")
    parser.add_argument("--messages", type=int, default=None, help=f"messages per contender and mode (default {MESSAGES})")
    parser.add_argument("--rounds", type=int, default=None, help=f"turns the contenders take (default: {ROUNDS}, --quick: 1)")
    args = parser.parse_args(argv)
    rows = run(args.quick, args.messages, args.rounds)
    print(table(rows))
    return rows


if __name__ == "__main__":
    main()
