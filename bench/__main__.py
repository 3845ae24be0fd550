"""`python -m bench`: run every benchmark and write docs/performance.md (see bench/run_all.py)."""

from __future__ import annotations

import sys

from bench.run_all import main

if __name__ == "__main__":  # spawned children import this module again: they must not rerun the benchmarks
    sys.exit(main())
