"""What `pbo check` imports: no simulator and no dynamics library once the machine has checked the
file before (their answers are kept in the result cache), and the same output either way."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pbo_runtime.objects import result_cache
from tests.support import REPO

PROBE = ("import json, sys\nfrom pbo_runtime.cli.main import main\n"
         "code = main(sys.argv[1:])\n"
         "print(json.dumps([code, sorted(sys.modules)]), file=sys.stderr)")
HEAVY = {"mujoco", "pinocchio"}


def check_in_a_process(file: str, cache: str) -> tuple[int, str, set[str]]:
    """`pbo check FILE` in a fresh interpreter with PBO_CACHE_DIR=`cache`: its exit code, output and modules."""
    env = {"PBO_CACHE_DIR": cache, "PATH": "/usr/bin:/bin", "HOME": str(Path.home())}
    done = subprocess.run([sys.executable, "-c", PROBE, "check", file], capture_output=True, text=True, timeout=120,
                          cwd=REPO, env=env)
    code, modules = json.loads(done.stderr.strip().splitlines()[-1])
    return code, done.stdout, set(modules)


@pytest.mark.multiprocess
def test_a_second_check_of_a_file_with_a_joint_loop_loads_neither_mujoco_nor_pinocchio_and_says_the_same(tmp_path):
    first = check_in_a_process("configs/pid_joint.yaml", str(tmp_path))
    second = check_in_a_process("configs/pid_joint.yaml", str(tmp_path))
    uncached = check_in_a_process("configs/pid_joint.yaml", "off")
    assert first[0] == second[0] == uncached[0] == 0
    assert first[1] == second[1] == uncached[1]
    assert uncached[2] >= HEAVY  # what the cache spares: the check does load them without it
    assert not HEAVY & second[2]


def test_a_kept_result_is_read_back_and_a_broken_one_is_computed_again(tmp_path, monkeypatch):
    monkeypatch.setenv("PBO_CACHE_DIR", str(tmp_path))
    calls = []

    def compute() -> dict[str, np.ndarray]:
        calls.append(1)
        return {"values": np.arange(3.0), "names": np.array(["a", "b"])}

    name = result_cache.fingerprint("test", b"\x00\x01", sources=(__file__,), libraries=("numpy",))
    made = result_cache.cached_arrays(name, compute)
    kept = result_cache.cached_arrays(name, compute)
    assert len(calls) == 1
    assert kept["values"].tolist() == made["values"].tolist() == [0.0, 1.0, 2.0] and kept["names"].tolist() == ["a", "b"]
    (tmp_path / f"{name}.npz").write_bytes(b"not an archive")
    assert result_cache.cached_arrays(name, compute)["values"].tolist() == [0.0, 1.0, 2.0]
    assert len(calls) == 2


@pytest.mark.parametrize("change", [{"parts": ("test", b"\x00\x02")}, {"libraries": ("numpy", "yaml")}],
                         ids=["another input", "another library"])
def test_an_entry_is_named_by_every_input_and_library(change):
    same = {"parts": ("test", b"\x00\x01"), "libraries": ("numpy",)}
    changed = {**same, **change}
    assert result_cache.fingerprint(*same["parts"], libraries=same["libraries"]) != \
        result_cache.fingerprint(*changed["parts"], libraries=changed["libraries"])


def test_no_folder_keeps_nothing_and_computes_each_time(monkeypatch):
    monkeypatch.setenv("PBO_CACHE_DIR", "off")
    calls = []
    for _ in range(2):
        result_cache.cached_arrays("any", lambda: calls.append(1) or {"x": np.zeros(1)})
    assert result_cache.cache_dir() is None and len(calls) == 2
