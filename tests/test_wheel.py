"""The wheel as a user gets it: built from the checkout, installed outside it, used from a folder of its own.

The wheel is built (`pip wheel --no-deps`) from a copy of the packaged sources, so the build leaves
nothing in the checkout; installed with `pip install --no-deps --target SITE`; and every command
runs with PYTHONPATH=SITE from a folder outside the repository. The test's interpreter has the
checkout installed editable: a `sitecustomize` put first on PYTHONPATH takes that install's finder
out of every process the commands start, so an import the wheel cannot answer fails instead of
quietly coming from the checkout. Then: the packages and every entry point (modules, drivers,
plants, robots) load from SITE; `pbo examples` copies out every file of configs/; each copied
config passes `pbo check`; `pbo schema` prints the copied schema; and the demo runs on the
simulated clock.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tomllib
import uuid
from pathlib import Path

import pytest

from tests.support import REPO

GROUPS = ("pbo.modules", "pbo.drivers", "pbo.plants", "pbo.robots")

GUARD = '''"""Run at interpreter start (by site) here and in every process a run starts: no editable install answers imports."""
import sys

sys.meta_path[:] = [f for f in sys.meta_path if "__editable__" not in getattr(f, "__module__", "")]
sys.path_hooks[:] = [h for h in sys.path_hooks if "__editable__" not in getattr(h, "__module__", "")]
sys.path[:] = [p for p in sys.path if "__editable__" not in p]
'''

PROBE = '''
import importlib, importlib.metadata, json, sys
found = {"packages": {name: importlib.import_module(name).__file__ for name in ("pbo_runtime", "rtpu", "modules", "drivers")},
         "entry_points": {}}
for group in %r:
    for point in importlib.metadata.entry_points(group=group):
        loaded = point.load()
        found["entry_points"].setdefault(group, {})[point.name] = [str(point.dist.locate_file("")),
                                                                   sys.modules[loaded.__module__].__file__]
found["imported"] = sorted(str(getattr(m, "__file__", None)) for n, m in list(sys.modules.items())
                           if n.split(".")[0] in ("pbo_runtime", "rtpu", "modules", "drivers"))
print(json.dumps(found))
''' % (GROUPS,)

CHECK_ALL = '''
import json, sys
from pbo_runtime.cli.main import main
print(json.dumps({path: main(["check", path]) for path in sys.argv[1:]}))
'''


def packaged_sources(into: Path) -> Path:
    """What the wheel is built from: pyproject.toml, README.md, the packages it names and configs/ (its package data)."""
    pyproject = tomllib.loads((REPO / "pyproject.toml").read_text())
    packages = {pattern.rstrip("*") for pattern in pyproject["tool"]["setuptools"]["packages"]["find"]["include"]}
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, into / name)
    for folder in sorted(packages | {"configs"}):
        shutil.copytree(REPO / folder, into / folder, symlinks=True,  # pbo_runtime/cli/example_configs stays a link
                        ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    return into


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> dict:
    """The wheel built and installed into SITE; the environment and the user's folder to run `pbo` in."""
    root = tmp_path_factory.mktemp("wheel")
    (root / "src").mkdir()
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "--wheel-dir", str(root / "dist"),
                            str(packaged_sources(root / "src"))], capture_output=True, text=True, timeout=300)
    assert built.returncode == 0, built.stdout + built.stderr
    wheel = next((root / "dist").glob("pbo_runtime-*.whl"))
    done = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--quiet", "--target", str(root / "site"),
                           str(wheel)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    (root / "guard").mkdir()
    (root / "guard" / "sitecustomize.py").write_text(GUARD)
    (root / "user").mkdir()
    env = {**os.environ, "PYTHONPATH": f"{root / 'guard'}{os.pathsep}{root / 'site'}"}
    return {"site": root / "site", "user": root / "user", "env": env, "pbo": str(root / "site" / "bin" / "pbo")}


def run(installed: dict, *command: str) -> subprocess.CompletedProcess:
    return subprocess.run(list(command), capture_output=True, text=True, timeout=120, cwd=installed["user"], env=installed["env"])


def within(path: str | Path, folder: Path) -> bool:
    return Path(path).resolve().is_relative_to(folder.resolve())


def shipped() -> list[str]:
    return sorted(p.relative_to(REPO / "configs").as_posix() for p in (REPO / "configs").rglob("*") if p.is_file())


@pytest.fixture(scope="module")
def examples(installed) -> Path:
    """`pbo examples` of the wheel, run in the user's folder: ./pbo-examples."""
    copied = run(installed, installed["pbo"], "examples")
    assert copied.returncode == 0, copied.stderr
    assert copied.stdout.startswith(f"wrote {len(shipped())} files into pbo-examples:\n"), copied.stdout
    return installed["user"] / "pbo-examples"


@pytest.mark.multiprocess
def test_the_wheel_loads_its_packages_and_every_entry_point_from_where_it_is_installed(installed):
    site = installed["site"]
    assert not within(installed["user"], REPO)
    probe = run(installed, sys.executable, "-c", PROBE)
    assert probe.returncode == 0, probe.stderr
    found = json.loads(probe.stdout)
    assert all(within(path, site) for path in found["packages"].values()), found["packages"]
    declared = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["entry-points"]
    for group in GROUPS:
        assert sorted(found["entry_points"].get(group, {})) == sorted(declared[group]), group
        for name, (distribution, module_file) in found["entry_points"][group].items():
            assert within(distribution, site) and within(module_file, site), (group, name, distribution, module_file)
    assert found["imported"] and all(within(path, site) for path in found["imported"] if path != "None")


@pytest.mark.multiprocess
def test_pbo_examples_of_the_wheel_copies_every_file_of_configs_and_the_schema_pbo_schema_prints(installed, examples):
    assert sorted(p.relative_to(examples).as_posix() for p in examples.rglob("*") if p.is_file()) == shipped()
    schema = run(installed, installed["pbo"], "schema")
    assert schema.returncode == 0 and schema.stdout == (examples / "pbo-subsystem.schema.json").read_text()


@pytest.mark.multiprocess
def test_every_config_copied_out_of_the_wheel_passes_pbo_check(installed, examples):
    check = run(installed, installed["pbo"], "check", "pbo-examples/pid_joint.yaml")
    assert check.returncode == 0 and "pbo-examples/pid_joint.yaml: ok: subsystem" in check.stdout, check.stderr
    configs = [f"pbo-examples/{name}" for name in shipped() if name.endswith(".yaml")]
    checked = run(installed, sys.executable, "-c", CHECK_ALL, *configs)  # the same main(), one process for all
    assert checked.returncode == 0, checked.stderr
    assert json.loads(checked.stdout.splitlines()[-1]) == {path: 0 for path in configs}, checked.stdout + checked.stderr


@pytest.mark.multiprocess
def test_the_demo_copied_out_of_the_wheel_runs_on_the_simulated_clock(installed, examples):
    demo = examples / "pid_joint.yaml"
    demo.write_text(re.sub(r"(?m)^subsystem: .*$", f"subsystem: wheel_{uuid.uuid4().hex[:8]}", demo.read_text(), count=1))
    ran = run(installed, installed["pbo"], "run", "pbo-examples/pid_joint.yaml", "--clock", "sim", "--duration", "1",
              "--no-live")
    assert ran.returncode == 0, ran.stdout + ran.stderr
    assert "starting subsystem 'wheel_" in ran.stdout and "run summary" in ran.stdout


def tutorial_commands() -> list[tuple[str, int]]:
    """docs/tutorial.md's `$` lines in order, with the exit status each should end with; `# by hand` ones left out."""
    text = (REPO / "docs" / "tutorial.md").read_text()
    lines = [line[2:] for block in re.findall(r"```console\n(.*?)```", text, re.S) for line in block.splitlines()
             if line.startswith("$ ")]
    return [(line, 1 if "# exits 1" in line else 0) for line in lines if "# by hand" not in line]


@pytest.mark.multiprocess
def test_the_tutorial_runs_command_by_command_from_the_wheel(installed, tmp_path):
    commands = tutorial_commands()
    assert [c for c, _ in commands][:2] == ["pbo examples", "pbo check pbo-examples/pid_joint.yaml"]
    env = {**installed["env"], "PATH": f"{installed['site'] / 'bin'}{os.pathsep}{os.environ['PATH']}"}
    for command, status in commands:
        done = subprocess.run(["bash", "-c", command], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
        assert done.returncode == status, f"$ {command}\n{done.stdout}\n{done.stderr}"
        if command == "pbo examples":  # names of their own: another run of the shipped ones may be live here
            for example in (tmp_path / "pbo-examples").glob("*.yaml"):
                example.write_text(re.sub(r"(?m)^subsystem: (.*)$", rf"subsystem: \1_{uuid.uuid4().hex[:6]}",
                                          example.read_text(), count=1))
    assert (tmp_path / "first.png").stat().st_size > 0 and (tmp_path / "ur5.png").stat().st_size > 0


def comment_commands(folder: Path) -> list[tuple[str, str]]:
    """(file, command) for each `pbo ...` command the shipped files' comments give, as written there."""
    found = []
    for path in sorted(folder.glob("*.yaml")):
        for line in path.read_text().splitlines():
            if line.lstrip().startswith("#"):
                for command in re.findall(r"(pbo (?:check|run|bus|graph) [A-Za-z0-9_]+\.yaml[^`;#)]*)", line):
                    found.append((path.name, command.strip()))
    return found


@pytest.mark.multiprocess
def test_every_command_in_the_shipped_files_comments_works_in_the_folder_pbo_examples_makes(installed, examples):
    """check, bus and graph run as written; a run's arguments are parsed by the CLI and its names (a
    configuration, an application, the configurations it alternates) found in the file: the files
    themselves run in the end-to-end tests."""
    from pbo_runtime.cli.main import _parser
    from pbo_runtime.config.loader import load_subsystem

    commands = comment_commands(examples)
    assert len(commands) >= 15 and all("configs/" not in command for _, command in commands)
    env = {**installed["env"], "PATH": f"{installed['site'] / 'bin'}{os.pathsep}{os.environ['PATH']}"}
    for file, command in commands:
        if command.startswith("pbo run"):
            args = _parser().parse_args(command.split()[1:])
            assert (examples / args.file).is_file(), command
            if args.file.endswith(("leader_follower.yaml",)):
                continue  # an application file: pbo check of it runs above
            subsystem = load_subsystem(examples / args.file)
            named = [args.config] + (args.alternate.split(",") if args.alternate else [])
            assert all(c is None or c in subsystem.configurations for c in named), command
            assert args.app is None or args.app in subsystem.applications, command
            continue
        done = subprocess.run(["bash", "-c", command], cwd=examples, env=env, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, f"{file}: $ {command}\n{done.stdout}\n{done.stderr}"


@pytest.mark.multiprocess
def test_the_wheel_ships_every_file_of_the_hmi(installed):
    def files(folder: Path) -> list[str]:
        return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())

    assert files(installed["site"] / "pbo_runtime" / "hmi") == files(REPO / "pbo_runtime" / "hmi")
