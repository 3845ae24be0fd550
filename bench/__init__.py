"""Benchmarks of the runtime, each against a baseline measured in the same run (issue 6).

`python -m bench` runs them all and writes docs/performance.md; `python -m bench.<name>` runs one.
"""
