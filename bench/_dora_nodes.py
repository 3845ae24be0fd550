"""The two Python nodes of bench/dora_peer.py's dataflow: a 1 kHz source and a sink that times arrivals.

dora-rs starts each as a process of its own (`path:` this interpreter, `args:` this file and a
role), so this file imports nothing of the project: only dora, pyarrow and numpy.

- source: on every tick of dora's timer (`dora/timer/millis/1`) it takes CLOCK_MONOTONIC and
  sends a 6-float64 item, [sequence number, time stamp in ns, 0, 0, 0, 0], on its output `item`;
  after `seconds` it writes how many items it sent and returns (its output closes, which stops the
  sink: every input closed);
- sink: blocked in `node.next()`, it takes CLOCK_MONOTONIC as each item arrives and keeps
  (sequence number, arrival - stamp); when the dataflow stops it writes them as a .npy file.

    python bench/_dora_nodes.py source|sink RESULT_FILE [SECONDS]
"""

from __future__ import annotations

import sys
import time

import numpy as np
import pyarrow as pa
from dora import Node

ITEM_WORDS = 6  # as the link between two subsystems: 6 float64 (48 bytes)


def source(result: str, seconds: float) -> None:
    node = Node()
    item = np.zeros(ITEM_WORDS)
    clock = time.monotonic_ns
    sent = 0
    end = None
    for event in node:
        if event["type"] == "STOP":
            break
        if event["type"] != "INPUT":
            continue
        now = clock()
        if end is None:
            end = now + int(seconds * 1e9)
        if now >= end:
            break
        sent += 1
        item[0] = sent
        item[1] = clock()  # the stamp, last thing before the send: the latency is dora's alone
        node.send_output("item", pa.array(item))
    with open(result, "w") as f:
        f.write(f"{sent}\n")


def sink(result: str) -> None:
    node = Node()
    clock = time.monotonic_ns
    seqs: list[int] = []
    latencies: list[int] = []
    for event in node:
        if event["type"] == "INPUT":
            arrival = clock()
            value = event["value"].to_numpy()
            seqs.append(int(value[0]))
            latencies.append(arrival - int(value[1]))
        elif event["type"] in ("STOP", "INPUT_CLOSED"):
            break
    np.save(result, np.array([seqs, latencies], dtype=np.int64).reshape(2, -1))


if __name__ == "__main__":
    role, path = sys.argv[1], sys.argv[2]
    if role == "source":
        source(path, float(sys.argv[3]))
    else:
        sink(path)
