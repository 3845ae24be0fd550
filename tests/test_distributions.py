"""The library's entry points and versions, read from the metadata folders as importlib.metadata reads them."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path

import pytest

from pbo_runtime.objects import distributions


@pytest.fixture
def only_path(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[str]]:
    """sys.path as the test sets it, the folders read afresh."""
    paths: list[str] = []
    monkeypatch.setattr(sys, "path", paths)
    distributions.metadata_folders.cache_clear()
    yield paths
    distributions.metadata_folders.cache_clear()


def installed(folder: Path, name: str, version: str, entry_points: str = "", egg: bool = False) -> None:
    info = folder / f"{name}-{version}.{'egg-info' if egg else 'dist-info'}"
    info.mkdir(parents=True)
    (info / ("PKG-INFO" if egg else "METADATA")).write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n\nBody\n")
    if entry_points:
        (info / "entry_points.txt").write_text(entry_points)


@pytest.mark.parametrize("group", ["pbo.modules", "pbo.drivers", "pbo.plants", "pbo.robots", "console_scripts"])
def test_the_installed_entry_points_are_those_importlib_metadata_reads(group: str) -> None:
    expected = [(point.name, point.value) for point in metadata.entry_points().select(group=group)]
    assert sorted((point.name, point.value) for point in distributions.entry_points(group)) == sorted(expected)


@pytest.mark.parametrize("name", ["numpy", "mujoco", "pbo-runtime", "PyYAML", "pbo_runtime"])
def test_an_installed_version_is_the_one_importlib_metadata_reads(name: str) -> None:
    assert distributions.version(name) == metadata.version(name)


def test_a_distribution_not_installed_has_no_version() -> None:
    assert distributions.version("no-such-distribution-here") is None


def test_the_first_of_two_distributions_with_one_name_on_the_path_wins(tmp_path: Path, only_path: list[str]) -> None:
    installed(tmp_path / "a", "Some.Plugin", "2.0", "[pbo.modules]\nshared = first:Module\n")
    installed(tmp_path / "b", "some_plugin", "1.0", "[pbo.modules]\nshared = second:Module\nother = second:Other\n")
    only_path.extend([str(tmp_path / "a"), str(tmp_path / "b")])
    assert [(p.name, p.value) for p in distributions.entry_points("pbo.modules")] == [("shared", "first:Module")]
    assert distributions.version("some-plugin") == "2.0"


def test_comments_blank_lines_and_other_groups_are_not_entry_points(tmp_path: Path, only_path: list[str]) -> None:
    installed(tmp_path, "plugin", "1.0", "# a comment\n\n[console_scripts]\ntool = plugin.cli:main\n\n"
                                         "[pbo.modules]\n  spaced   =  plugin.mod : Thing [extra]\n")
    only_path.append(str(tmp_path))
    points = list(distributions.entry_points("pbo.modules"))
    assert [(p.name, p.value, p.group) for p in points] == [("spaced", "plugin.mod : Thing [extra]", "pbo.modules")]


def test_an_egg_info_folder_is_read_too(tmp_path: Path, only_path: list[str]) -> None:
    installed(tmp_path, "old_style", "0.3", "[pbo.drivers]\nlegacy = old_style:Driver\n", egg=True)
    only_path.append(str(tmp_path))
    assert [p.name for p in distributions.entry_points("pbo.drivers")] == ["legacy"]
    assert distributions.version("old-style") == "0.3"


def test_an_entry_point_loads_the_object_it_names_or_its_module() -> None:
    assert distributions.EntryPoint("x", "os.path:join", "g").load() is __import__("os").path.join
    assert distributions.EntryPoint("x", "json", "g").load() is __import__("json")
    with pytest.raises(ValueError, match="names no module"):
        distributions.EntryPoint("x", "not a value!", "g").load()
