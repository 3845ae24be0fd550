"""`pbo examples [DIR]`: the example configs and their schema copied out of the package, ready to check and run.

In-process, against the checkout's package (whose `example_configs/` is a link to `configs/`);
tests/test_wheel.py does the same from a built wheel installed outside the checkout.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from pbo_runtime.cli.examples import EXAMPLES, shipped_files
from pbo_runtime.cli.main import main
from pbo_runtime.config.file_kind import is_application_file
from pbo_runtime.reports.schema import schema_text
from tests.support import REPO

SCHEMA = "pbo-subsystem.schema.json"
CONFIGS = sorted(path.name for path in (REPO / "configs").glob("*.yaml"))


@pytest.fixture(scope="module")
def copied(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("user") / "my-examples"
    assert main(["examples", str(folder)]) == 0
    return folder


def test_the_shipped_examples_are_the_repository_configs_folder():
    assert EXAMPLES.resolve() == (REPO / "configs").resolve()
    configs = REPO / "configs"
    assert shipped_files() == sorted(p.relative_to(configs).as_posix() for p in configs.rglob("*") if p.is_file())
    assert SCHEMA in shipped_files() and set(CONFIGS) <= set(shipped_files())


def test_the_shipped_schema_is_what_pbo_schema_prints():
    assert (EXAMPLES / SCHEMA).read_text() == schema_text(), "regenerate it: pbo schema -o configs/pbo-subsystem.schema.json"


def test_examples_copies_every_shipped_file_and_says_what_it_wrote(tmp_path, capsys):
    assert main(["examples", str(tmp_path / "mine")]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"wrote {len(shipped_files())} files into {tmp_path / 'mine'}:\n")
    for name in shipped_files():
        assert f"\n  {name}\n" in out
        assert (tmp_path / "mine" / name).read_bytes() == (EXAMPLES / name).read_bytes()
    assert f"next: pbo check {tmp_path / 'mine' / 'pid_joint.yaml'}; pbo run " in out


def test_examples_writes_into_pbo_examples_of_the_current_folder_by_default(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["examples"]) == 0
    assert "into pbo-examples:" in capsys.readouterr().out
    assert sorted(p.relative_to(tmp_path / "pbo-examples").as_posix() for p in (tmp_path / "pbo-examples").rglob("*")
                  if p.is_file()) == shipped_files()


@pytest.mark.parametrize("name", [n for n in CONFIGS if not is_application_file(REPO / "configs" / n)])
def test_a_copied_config_names_the_schema_copied_beside_it(copied, name):
    first = re.fullmatch(r"# yaml-language-server: \$schema=(\S+)", (copied / name).read_text().splitlines()[0])
    assert first and (copied / name).parent.joinpath(first.group(1)).read_text() == schema_text()


@pytest.mark.parametrize("name", CONFIGS)
def test_every_copied_config_passes_the_checker(copied, name, capsys):
    assert main(["check", str(copied / name)]) == 0, capsys.readouterr().err


def test_examples_again_leaves_equal_files_as_they_were(tmp_path, capsys):
    assert main(["examples", str(tmp_path)]) == 0
    capsys.readouterr()
    assert main(["examples", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"left {len(shipped_files())} files there as they were: equal to the shipped ones\n")
    assert "wrote" not in out


def test_examples_refuses_to_overwrite_an_edited_file_and_writes_nothing(tmp_path, capsys):
    assert main(["examples", str(tmp_path)]) == 0
    edited = (tmp_path / "join.yaml").read_text() + "# my change\n"
    (tmp_path / "join.yaml").write_text(edited)
    (tmp_path / "pid_joint.yaml").unlink()
    capsys.readouterr()
    assert main(["examples", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert re.fullmatch(rf"error: {re.escape(str(tmp_path))}: 1 file differs from the shipped examples \(join\.yaml\); "
                        r"nothing written: --force overwrites them, or give another folder\n", err)
    assert (tmp_path / "join.yaml").read_text() == edited
    assert not (tmp_path / "pid_joint.yaml").exists()


def test_examples_force_overwrites_an_edited_file(tmp_path, capsys):
    assert main(["examples", str(tmp_path)]) == 0
    (tmp_path / "join.yaml").write_text("mine\n")
    capsys.readouterr()
    assert main(["examples", str(tmp_path), "--force"]) == 0
    assert "\n  join.yaml (overwritten)\n" in capsys.readouterr().out
    assert (tmp_path / "join.yaml").read_bytes() == (EXAMPLES / "join.yaml").read_bytes()


@pytest.mark.parametrize("where, message", [
    ("a_file", "error: {folder} is a file, not a folder: give a folder for the examples, e.g. pbo examples my-examples"),
    ("a_file/below", "error: cannot make the folder {folder}: Not a directory: give a folder you can write to"),
])
def test_examples_into_a_folder_it_cannot_make_is_one_line_and_exit_1(tmp_path, capsys, where, message):
    (tmp_path / "a_file").write_text("not a folder\n")
    assert main(["examples", str(tmp_path / where)]) == 1
    assert capsys.readouterr().err == message.format(folder=tmp_path / where) + "\n"
