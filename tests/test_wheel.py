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

import itertools
import json
import os
import re
import shlex
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

PROBE = f"GROUPS = {GROUPS!r}\n" + '''
import importlib, importlib.metadata, json, sys
found = {"packages": {name: importlib.import_module(name).__file__ for name in ("pbo_runtime", "rtpu", "modules", "drivers")},
         "entry_points": {}}
for group in GROUPS:
    for point in importlib.metadata.entry_points(group=group):
        loaded = point.load()
        found["entry_points"].setdefault(group, {})[point.name] = [str(point.dist.locate_file("")),
                                                                   sys.modules[loaded.__module__].__file__]
found["imported"] = sorted(str(getattr(m, "__file__", None)) for n, m in list(sys.modules.items())
                           if n.split(".")[0] in ("pbo_runtime", "rtpu", "modules", "drivers"))
print(json.dumps(found))
'''

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
                for command in re.findall(r"(pbo (?:check|run|bus|graph) [A-Za-z0-9_/]+\.yaml[^`;#)]*)", line):
                    found.append((path.name, command.strip()))
    return found


def assert_a_runs_names_are_in_its_file(folder: Path, command: str) -> None:
    """`pbo run ...` parsed by the CLI's own parser in `folder`: its file is there, and the names it
    gives (a configuration, an application, the configurations it alternates) are in that file. An
    application file's names are checked by `pbo check` of it; the files themselves run in the end-to-end tests."""
    from pbo_runtime.config.loader import load_subsystem

    try:
        args = parse_cli(command_words(command)[1:])
    except SystemExit as refused:
        raise AssertionError(f"the CLI refuses its arguments: {command}") from refused
    assert (folder / args.file).is_file(), command
    if re.search(r"(?m)^subsystems:", (folder / args.file).read_text()):
        return
    subsystem = load_subsystem(folder / args.file)
    named = [args.config] + (args.alternate.split(",") if args.alternate else [])
    assert all(c is None or c in subsystem.configurations for c in named), command
    assert args.app is None or args.app in subsystem.applications, command


@pytest.mark.multiprocess
def test_every_command_in_the_shipped_files_comments_works_in_the_folder_pbo_examples_makes(installed, examples):
    """check, bus and graph run as written; a run's arguments are parsed and its names found in the file."""
    commands = comment_commands(examples)
    assert len(commands) >= 15 and all("configs/" not in command for _, command in commands)
    env = {**installed["env"], "PATH": f"{installed['site'] / 'bin'}{os.pathsep}{os.environ['PATH']}"}
    for file, command in commands:
        if command.startswith("pbo run"):
            assert_a_runs_names_are_in_its_file(examples, command)
            continue
        done = subprocess.run(["bash", "-c", command], cwd=examples, env=env, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, f"{file}: $ {command}\n{done.stdout}\n{done.stderr}"


@pytest.mark.multiprocess
def test_the_wheel_ships_every_file_of_the_hmi(installed):
    def files(folder: Path) -> list[str]:
        return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())

    assert files(installed["site"] / "pbo_runtime" / "hmi") == files(REPO / "pbo_runtime" / "hmi")


USER_PAGES_LEFT_OUT = {"contributing.md": "for a checkout", "performance.md": "the benchmarks' own commands",
                       "tutorial.md": "followed command by command above"}
NOT_COMMANDS = {"pbo run (supervisor, job control) ── signal queue per RTPU ──▶ python -m rtpu ... (one per RTPU)":
                "architecture.md's diagram"}
LIVE_VERBS = {"status", "on", "off", "clear", "switch", "job", "event", "play", "spawn", "kill", "replace", "set",
              "app", "save", "svar", "stop", "clean", "ros2"}
RAN_VERBS = {"check", "bus", "graph", "lexicon", "place", "schema", "robot", "examples", "runs", "completion", "plot", "log",
             "allocate", "--help"}
FILE_TOKEN = re.compile(r"/|\.(ya?ml|json|mcap|csv|png|svg|pdf|urdf|npy)$")
OUTPUT_FLAGS = {"-o", "--out", "--report"}


def docs_commands(docs: Path = REPO / "docs") -> list[tuple[str, str]]:
    """(page, command) for each `pbo` command of docs/'s user pages (all but USER_PAGES_LEFT_OUT), as written.

    In a fenced code block: every line that starts with `pbo ` (or `.venv/bin/pbo `) after an
    optional prompt (`$ `, `host$ `), but not output (`pbo: ...`, `pbo hmi: ...`); `&&` and `;` split
    a line into its commands. Inline: a backticked `pbo ...` that names a file (a word with a `/` or
    a file's extension), its whitespace joined across line breaks. What each one then gets is
    what_to_do's.
    """
    found = []
    for page in sorted(docs.glob("*.md")):
        if page.name in USER_PAGES_LEFT_OUT:
            continue
        text = page.read_text()
        lines = [line.strip() for block in re.findall(r"(?ms)^ *```[^\n]*\n(.*?)^ *```", text) for line in block.splitlines()]
        for line in lines:
            line = re.sub(r"^\S*\$ ", "", line)
            if re.match(r"(\.venv/bin/)?pbo [^:\s]+(\s|$)", line):
                found += [(page.name, part.strip()) for part in re.split(r"&&|;", line) if "pbo " in part]
        prose = re.sub(r"(?ms)^ *```.*?^ *```", "", text)
        for span in re.findall(r"`(pbo [^`]+)`", prose):
            command = " ".join(span.split())
            if any(FILE_TOKEN.search(word) for word in command.split()):
                found.append((page.name, command))
    return found


def command_words(command: str) -> list[str]:
    """The command's words, up to a comment or a shell redirection, pipe or `&`."""
    words = shlex.split(command, comments=True)
    return words[:next((i for i, w in enumerate(words) if w in {">", ">>", "|", "&", "2>"}), len(words))]


def input_files(words: list[str]) -> list[str]:
    """The files a command reads: its words that name a file, but not those after an output flag."""
    return [w for before, w in itertools.pairwise(words) if before not in OUTPUT_FLAGS and FILE_TOKEN.search(w)
            and not w.startswith("package://")]


def runs_read(commands: list[str]) -> set[str]:
    """The run directories (`runs/NAME`) and run reports (`run.json`) the commands read."""
    found = set()
    for command in commands:
        if command not in NOT_COMMANDS and what_to_do(command) == "run":
            for word in input_files(command_words(command)):
                found |= {m.group(0) for m in [re.match(r"runs/[^/]+|run\.json$", word)] if m}
    return found


def what_to_do(command: str) -> str:
    """`run` (as written, exit status 0), `parse-run` (a `pbo run`: the CLI's parser takes its
    arguments, its file and the names it gives are there), or why it is not run ("not run: ...": a
    synopsis with placeholders such as FILE; a live run's verb; the HMI; a file the reader writes,
    i.e. a .yaml not under pbo-examples/), its arguments parsed all the same. A command that names
    configs/ or .venv/, that the parser refuses, or that fits none of these fails the test."""
    if command in NOT_COMMANDS:
        return f"not run: {NOT_COMMANDS[command]}, not a command"
    words = command_words(command)
    assert words[0] == "pbo" and not any(w.startswith(("configs/", ".venv/")) for w in words), \
        f"written for a checkout, not for a wheel user after `pbo examples`: {command}"
    if any(re.search(r"\b[A-Z][A-Z_]{2,}\b|^\[|\.\.\.", w) for w in words[1:]):
        return "not run: a synopsis (placeholders)"
    verb = words[1]
    try:
        if verb != "--help":
            parse_cli(words[1:])
    except SystemExit as refused:
        raise AssertionError(f"the CLI refuses its arguments: {command}") from refused
    inputs = input_files(words)
    if verb in LIVE_VERBS:
        return "not run: acts on a live run (arguments parsed)"
    if verb == "hmi":
        return "not run: serves the browser HMI (arguments parsed)"
    if any(not w.startswith("pbo-examples/") and not w.startswith("runs/") and w.endswith((".yaml", ".yml")) for w in inputs):
        return "not run: names a file of the reader's own (arguments parsed)"
    if verb == "run":
        return "parse-run"
    if verb in RAN_VERBS:
        return "run"
    raise AssertionError(f"cannot classify this docs command: say in tests/test_wheel.py how to test it: {command}")


def parse_cli(words: list[str]):
    """The CLI's own parser on a command's words (the one place this test file reaches for it)."""
    from pbo_runtime.cli.main import _parser

    return _parser().parse_args(words)


def make_the_runs_read(installed: dict, folder: Path, made: set[str]) -> None:
    """The run directories and reports the docs' commands read, made in `folder` by one run of
    pbo-examples/pid_joint.yaml on the simulated clock."""
    if made:
        ran = run(installed, installed["pbo"], "run", str(folder / "pbo-examples" / "pid_joint.yaml"), "--clock", "sim",
                  "--duration", "1", "--no-live", "--out", str(folder / "runs" / "made"), "--report", str(folder / "made.json"))
        assert ran.returncode == 0, ran.stdout + ran.stderr
    for name in made:
        (folder / name).symlink_to(folder / ("made.json" if name.endswith(".json") else "runs/made"))


@pytest.mark.multiprocess
def test_every_pbo_command_in_the_docs_works_for_a_wheel_user_in_the_folder_pbo_examples_makes(installed, tmp_path):
    """The user pages' commands (docs_commands says which lines) are run as written in a folder of
    their own, `pbo examples` first: each must end with status 0; the run directories and reports
    they read are made first by a run of the demo. A `pbo run` is parsed and its names found in its
    file (the files run in the end-to-end tests). What needs a live run, a browser or the reader's
    own file is parsed and listed, not run; a command the test cannot classify fails it."""
    commands = sorted(dict.fromkeys(command for _, command in docs_commands()),
                      key=lambda command: command_words(command) != ["pbo", "examples"])
    assert command_words(commands[0]) == ["pbo", "examples"], "no page says `pbo examples`"
    env = {**installed["env"], "PATH": f"{installed['site'] / 'bin'}{os.pathsep}{os.environ['PATH']}"}
    ran, not_run = [], []
    for command in commands:
        action = what_to_do(command)
        if action == "parse-run":
            assert_a_runs_names_are_in_its_file(tmp_path, command)
            ran.append(command)
        elif action == "run":
            words = command_words(command)
            done = subprocess.run([installed["pbo"], *words[1:]], cwd=tmp_path, env=env, capture_output=True, text=True,
                                  timeout=120)
            assert done.returncode == 0, f"$ {command}\n{done.stdout}\n{done.stderr}"
            ran.append(command)
        else:
            not_run.append(f"{command}: {action}")
        if command == commands[0]:  # names of their own: another run of the shipped ones may be live here
            for example in (tmp_path / "pbo-examples").glob("*.yaml"):
                example.write_text(re.sub(r"(?m)^subsystem: (.*)$", rf"subsystem: \1_{uuid.uuid4().hex[:6]}",
                                          example.read_text(), count=1))
            make_the_runs_read(installed, tmp_path, runs_read(commands))
    print("not run:", *not_run, sep="\n  ")
    assert len(ran) >= 25, (ran, not_run)


@pytest.mark.parametrize(("command", "said"), [
    ("pbo check configs/pid_joint.yaml", "written for a checkout"),
    (".venv/bin/pbo check pbo-examples/pid_joint.yaml", "written for a checkout"),
    ("pbo chekc pbo-examples/pid_joint.yaml", "the CLI refuses its arguments"),
    ("pbo run pbo-examples/pid_joint.yaml --durration 3", "the CLI refuses its arguments"),
])
def test_a_docs_command_written_for_a_checkout_or_that_the_cli_refuses_fails(command, said):
    with pytest.raises(AssertionError, match=said):
        what_to_do(command)


def test_a_docs_command_of_a_verb_the_test_does_not_know_fails_it(monkeypatch):
    monkeypatch.setattr(sys.modules[__name__], "RAN_VERBS", RAN_VERBS - {"graph"})
    with pytest.raises(AssertionError, match="cannot classify"):
        what_to_do("pbo graph pbo-examples/pid_joint.yaml")


def test_docs_commands_takes_prompted_and_bare_lines_of_code_blocks_and_inline_ones_naming_a_file(tmp_path):
    (tmp_path / "page.md").write_text("""Run `pbo check FILE`, then `pbo bus
pbo-examples/pid_joint.yaml`; `pbo status` needs a run.

```
$ pbo check pbo-examples/a.yaml && pbo graph pbo-examples/a.yaml  # two
pbo: a message, not a command
host$ pbo run pbo-examples/a.yaml
pbo lexicon
```
""")
    assert [command for _, command in docs_commands(tmp_path)] == [
        "pbo check pbo-examples/a.yaml", "pbo graph pbo-examples/a.yaml  # two", "pbo run pbo-examples/a.yaml",
        "pbo lexicon", "pbo bus pbo-examples/pid_joint.yaml"]
    assert [what_to_do(c) for c in ("pbo check FILE", "pbo status", "pbo check arm.yaml", "pbo lexicon")] == [
        "not run: a synopsis (placeholders)", "not run: acts on a live run (arguments parsed)",
        "not run: names a file of the reader's own (arguments parsed)", "run"]
