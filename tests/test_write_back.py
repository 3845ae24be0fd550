"""The one checked write-back (edit.write_back): a draft beside the file, checked, then moved over it;
every way it can fail leaves the file as it was and no draft behind."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from pbo_runtime.config.loader import check_file
from pbo_runtime.edit.write_back import WriteRefused, write_checked
from tests.support import DEMO

CLEAN = DEMO.read_text()
CHANGED = CLEAN + "# a comment the edit added\n"
BROKEN = CLEAN + "\nunknown_section: 1\n"


def a_file(folder: Path, mode: int = 0o640) -> Path:
    file = folder / "subsystem.yaml"
    file.write_text(CLEAN)
    file.chmod(mode)
    return file


def test_a_text_that_checks_clean_replaces_the_file_with_its_mode_kept_and_no_draft_left(tmp_path):
    file = a_file(tmp_path)
    result = write_checked(str(file), CHANGED)
    assert result.ok and result.subsystem is not None
    assert file.read_text() == CHANGED
    assert stat.S_IMODE(file.stat().st_mode) == 0o640
    assert sorted(p.name for p in tmp_path.iterdir()) == ["subsystem.yaml"]


def test_a_new_file_gets_the_mode_any_new_file_gets(tmp_path):
    file = tmp_path / "new.yaml"
    umask = os.umask(0o022)
    try:
        write_checked(str(file), CLEAN)
    finally:
        os.umask(umask)
    assert file.read_text() == CLEAN and stat.S_IMODE(file.stat().st_mode) == 0o644


def test_a_text_that_does_not_check_clean_leaves_the_file_as_it_was_and_names_the_first_error_in_it(tmp_path):
    file = a_file(tmp_path)
    with pytest.raises(WriteRefused,
                       match=rf"^not saved: {file} would have 1 error, the first: {file}:\d+:\d+: error\[E1\d\d\]") \
            as refused:
        write_checked(str(file), BROKEN)
    assert len(refused.value.errors) == 1 and refused.value.first.startswith(f"{file}:")
    assert file.read_text() == CLEAN
    assert sorted(p.name for p in tmp_path.iterdir()) == ["subsystem.yaml"]


def test_pbo_saves_text_is_written_even_when_it_does_not_check_clean_and_the_check_says_so(tmp_path):
    file = a_file(tmp_path)
    result = write_checked(str(file), BROKEN, even_with_errors=True)
    assert file.read_text() == BROKEN and not result.ok and result.subsystem is None
    assert check_file(file).errors[0].code == result.errors[0].code


@pytest.mark.parametrize(("where", "says"), [
    (lambda folder: folder / "no such folder" / "subsystem.yaml", "cannot write beside {file}: No such file or directory"),
    (lambda folder: folder / "a folder", "cannot write {file}: Is a directory"),
])
def test_a_file_that_cannot_be_written_is_named_with_the_systems_reason_and_left_as_it_was(tmp_path, where, says):
    file = where(tmp_path)
    if file.name == "a folder":
        file.mkdir()
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    with pytest.raises(WriteRefused, match=f"^{says.format(file=file)}$") as refused:
        write_checked(str(file), CLEAN)
    assert refused.value.errors == [] and refused.value.first == ""
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before
