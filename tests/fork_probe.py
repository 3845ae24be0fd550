"""A stand-in child for the fork server's tests: `main(argv)` says what it was started as, then ends as told.

    main([OUT, MODE, CODE, "--parent", PID])

MODE report: writes what a child must be (its pid and parent, its parent-death signal, its
threads, its scheduler, OPENBLAS_NUM_THREADS, its command line, the modules it has) to OUT as JSON and returns CODE;
raise: fails before it is ready (an exception out of main); sleep: writes its pid, then waits to be killed.
"""

from __future__ import annotations

import ctypes
import json
import os
import signal
import sys

from pbo_runtime.ipc.process import become_child

PR_GET_PDEATHSIG = 2


def main(argv: list[str] | None = None) -> int:
    out, mode, code, _, parent = argv if argv is not None else sys.argv[1:]
    become_child(int(parent))
    if mode == "raise":
        raise RuntimeError("a child that fails before it is ready")
    death = ctypes.c_int(0)
    ctypes.CDLL(None).prctl(PR_GET_PDEATHSIG, ctypes.byref(death), 0, 0, 0)
    with open(f"/proc/{os.getpid()}/cmdline", encoding="utf-8") as stream:
        cmdline = stream.read().replace("\0", " ")
    said = {"pid": os.getpid(), "ppid": os.getppid(), "death_signal": death.value,
            "threads": len(os.listdir("/proc/self/task")), "scheduler": os.sched_getscheduler(0),
            "openblas": os.environ.get("OPENBLAS_NUM_THREADS"), "cmdline": cmdline, "modules": sorted(sys.modules)}
    with open(out + ".part", "w", encoding="utf-8") as stream:
        json.dump(said, stream)
    os.replace(out + ".part", out)  # whole: a test waits for the file, then reads it
    if mode == "sleep":
        signal.pause()
    return int(code)
