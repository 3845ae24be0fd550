"""The core install runs subsystems and the CLI; a verb that needs an optional extra says which.

Run as a user without the extras would: every process of the run (CLI, RTPUs, plant) starts with
the extras' packages made unimportable (a sitecustomize on PYTHONPATH), as if never installed.
"""

from __future__ import annotations

import os
import subprocess

import pytest

from tests.support import PBO, REPO, demo_copy

WITHOUT = ("fastapi", "uvicorn", "websockets", "starlette", "matplotlib", "zenoh", "cyclonedds")


@pytest.fixture
def core_only(tmp_path) -> dict[str, str]:
    """An environment whose Python processes cannot import the extras' packages."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text("import sys\n" + "".join(f"sys.modules[{name!r}] = None\n" for name in WITHOUT))
    return {**os.environ, "PYTHONPATH": str(site)}


def pbo(env: dict[str, str], cwd, *arguments: str) -> subprocess.CompletedProcess:
    return subprocess.run([*PBO, *arguments], cwd=cwd, env=env, capture_output=True, text=True, timeout=120)


@pytest.mark.multiprocess
def test_the_core_install_checks_and_runs_a_subsystem(core_only, tmp_path):
    config = demo_copy(tmp_path, "core_only")
    assert pbo(core_only, tmp_path, "check", str(config)).returncode == 0
    done = pbo(core_only, tmp_path, "run", str(config), "--clock", "sim", "--duration", "0.3", "--no-live", "--out", "out")
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "out" / "pid_joint.mcap").is_file()


@pytest.mark.multiprocess
@pytest.mark.parametrize("arguments, verb, extra, missing", [
    (["hmi", "CONFIG"], "pbo hmi", "hmi", "fastapi"),
    (["plot", "CONFIG", "-o", "p.png"], "pbo plot", "plot", "matplotlib"),
    (["graph", "CONFIG", "-o", "g.svg"], "pbo graph -o g.svg", "plot", "matplotlib"),
    (["bus", "CONFIG", "--plot", "b.png"], "pbo bus --plot", "plot", "matplotlib"),
    (["ros2", "jobs", "reach"], "pbo ros2 jobs", "ros2", "cyclonedds"),
])
def test_a_verb_that_needs_a_missing_extra_says_which_in_one_line_and_exits_1(core_only, tmp_path, arguments, verb, extra,
                                                                             missing):
    config = REPO / "configs" / "pid_joint.yaml"
    done = pbo(core_only, tmp_path, *[str(config) if a == "CONFIG" else a for a in arguments])
    assert done.returncode == 1
    assert done.stderr == (f"error: {verb} needs the '{extra}' extra ({missing} is not installed): "
                           f"pip install 'pbo-runtime[{extra}]'\n")
    assert list(tmp_path.glob("*.png")) == list(tmp_path.glob("*.svg")) == []
