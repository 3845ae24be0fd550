"""The dataclass code kept on disk (`objects.dataclass_code`): classes made from it are the same classes,
a later process compiles nothing, and a file it cannot trust or read costs compiling, never the run."""

from __future__ import annotations

import dataclasses
import json
import marshal
import os
import subprocess
import sys
from pathlib import Path

import pytest

from pbo_runtime.objects import dataclass_code
from tests.support import REPO

FILE_NAME = f"dataclass-code.{sys.implementation.cache_tag}.marshal"
# a fresh interpreter: installs the cache, makes a dataclass per name (fields named after it) or imports
# the module so named, says how many methods it compiled, saves
PROBE = ("import importlib, json, sys\nfrom pbo_runtime.objects import dataclass_code\n"
         "installed = dataclass_code.install()\nimport dataclasses\n"
         "for name in sys.argv[1:]:\n"
         "    if name.startswith('pbo_runtime.'):\n        importlib.import_module(name)\n"
         "    else:\n        dataclasses.make_dataclass(name, [(f'{name}_x', int), (f'{name}_y', float, 0.0)], frozen=True)\n"
         "print(json.dumps([installed, dataclass_code.compiled, 'exec' in vars(dataclasses)]))\n"
         "dataclass_code.save()")


def make_classes() -> tuple[type, type]:
    """The same class bodies each call, using what `dataclasses` generates most."""

    @dataclasses.dataclass(frozen=True, slots=True, order=True)
    class Point:
        x: int
        y: float = 0.5
        tags: tuple[str, ...] = dataclasses.field(default_factory=tuple)
        label: str = dataclasses.field(default="p", kw_only=True, compare=False)

        def __post_init__(self) -> None:
            if self.x < 0:
                raise ValueError("x must not be negative")

    @dataclasses.dataclass(kw_only=True, unsafe_hash=True)
    class Box:
        name: str = "box"
        sizes: list[int] = dataclasses.field(default_factory=list, hash=False)

        def __post_init__(self) -> None:
            self.sizes.append(len(self.name))

    return Point, Box


def behaviour(point: type, box: type) -> list[object]:
    """What a user of the classes sees: values, comparisons, hashes, errors, signatures."""
    seen: list[object] = []
    a, b = point(1), point(2, 1.5, ("t",), label="q")
    seen += [repr(a), repr(b), a == point(1, label="other"), a < b, sorted([b, a]) == [a, b], hash(a) == hash(point(1))]
    seen += [point.__slots__, [f.name for f in dataclasses.fields(point)], point.__init__.__annotations__,
             point.__init__.__kwdefaults__, point.__init__.__defaults__, box.__init__.__annotations__]
    for attempt in (lambda: point(-1), lambda: setattr(a, "x", 3), lambda: point(1, 2, (), "positional"), lambda: box("n")):
        with pytest.raises(Exception) as raised:
            attempt()
        seen.append((type(raised.value).__name__, str(raised.value)))
    first, second = box(name="abc"), box()
    seen += [repr(first), repr(second), first == box(name="abc"), hash(first) == hash(box(name="abc")), second.sizes]
    return seen


@pytest.fixture
def kept_code(tmp_path, monkeypatch):
    """`dataclass_code` as in a process that has not installed it, keeping its code in `tmp_path`."""
    monkeypatch.setenv("PBO_CACHE_DIR", str(tmp_path))
    for name, empty in (("_kept", {}), ("_code", {}), ("_new", {}), ("_used", set()), ("_path", None), ("compiled", 0)):
        monkeypatch.setattr(dataclass_code, name, empty)
    monkeypatch.setattr(dataclasses, "exec", None, raising=False)  # (so that what install sets is undone)
    monkeypatch.delattr(dataclasses, "exec")
    return dataclass_code


def forget_in_memory(module) -> None:
    """As a new process starts: nothing installed, nothing compiled (the file stays)."""
    module._kept.clear()
    module._code.clear()
    module._new.clear()
    module._used.clear()
    module._path = None
    module.compiled = 0


def test_a_class_made_from_kept_code_behaves_as_one_compiled_by_dataclasses(kept_code):
    compiled_by_dataclasses = behaviour(*make_classes())
    assert kept_code.install()
    compiled_here = behaviour(*make_classes())
    assert kept_code.compiled > 0
    kept_code.save()
    forget_in_memory(kept_code)
    assert kept_code.install()
    assert not kept_code.install()  # (once a process)
    read_back = behaviour(*make_classes())
    assert kept_code.compiled == 0
    assert read_back == compiled_here == compiled_by_dataclasses


def define_in_a_process(cache: Path | str, *names: str) -> tuple[bool, int, bool]:
    """PROBE in a fresh interpreter: installed, methods compiled, `dataclasses` patched."""
    done = subprocess.run([sys.executable, "-c", PROBE, *names], capture_output=True, text=True, timeout=120, cwd=REPO,
                          env={**os.environ, "PBO_CACHE_DIR": str(cache)}, check=True)
    installed, compiled, patched = json.loads(done.stdout.strip().splitlines()[-1])
    return installed, compiled, patched


@pytest.mark.multiprocess
def test_a_second_process_making_the_runtimes_dataclasses_compiles_none_of_their_methods(tmp_path):
    modules = ("pbo_runtime.config.model", "pbo_runtime.ipc.messages", "Extra")
    first = define_in_a_process(tmp_path, *modules)
    second = define_in_a_process(tmp_path, *modules)
    assert first[0] and first[1] > 50
    assert second == (True, 0, True)
    assert (tmp_path / FILE_NAME).stat().st_mode & 0o777 == 0o600


@pytest.mark.multiprocess
def test_a_second_pbo_check_finds_every_method_kept_and_leaves_the_file_as_it_was(tmp_path):
    env = {**os.environ, "PBO_CACHE_DIR": str(tmp_path)}
    check = [sys.executable, "-m", "pbo_runtime.cli", "check", "configs/pid_joint.yaml"]
    subprocess.run(check, cwd=REPO, env=env, capture_output=True, timeout=120, check=True)
    written = (tmp_path / FILE_NAME).stat()
    subprocess.run(check, cwd=REPO, env=env, capture_output=True, timeout=120, check=True)
    assert (tmp_path / FILE_NAME).stat().st_ino == written.st_ino  # (a save replaces the file: a new inode)
    assert len(dataclass_code.read(str(tmp_path / FILE_NAME))) > 100


@pytest.mark.multiprocess
def test_a_forked_child_has_the_code_its_parent_compiled_but_not_its_parents_to_save(kept_code):
    kept_code.install()
    make_classes()
    compiled = kept_code.compiled
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # (the child never returns to pytest)
        try:
            os.close(read_end)
            make_classes()
            os.write(write_end, json.dumps([kept_code.compiled, len(kept_code._new)]).encode())
        finally:
            os._exit(0)
    os.close(write_end)
    with os.fdopen(read_end) as said:
        assert json.loads(said.read()) == [0, 0]
    os.waitpid(pid, 0)
    assert compiled > 0 and kept_code.compiled == len(kept_code._new) == compiled


@pytest.mark.multiprocess
def test_two_processes_making_different_classes_leave_a_file_holding_both(tmp_path):
    define_in_a_process(tmp_path, "Left")
    define_in_a_process(tmp_path, "Right")
    texts = "".join(dataclass_code.read(str(tmp_path / FILE_NAME)))
    assert "Left_x" in texts and "Right_x" in texts
    assert define_in_a_process(tmp_path, "Left", "Right")[1] == 0


@pytest.mark.multiprocess
def test_no_cache_folder_writes_nothing_and_leaves_dataclasses_as_it_is(tmp_path):
    env_home = tmp_path / "home"
    done = subprocess.run([sys.executable, "-c", PROBE, "Any"], capture_output=True, text=True, timeout=120, cwd=REPO,
                          env={**os.environ, "PBO_CACHE_DIR": "off", "HOME": str(env_home),
                               "XDG_CACHE_HOME": str(tmp_path / "xdg")}, check=True)
    installed, compiled, patched = json.loads(done.stdout.strip().splitlines()[-1])
    assert not installed and not patched and compiled == 0
    assert list(tmp_path.iterdir()) == []


def writable_by_group(path: Path) -> None:
    path.chmod(0o620)


def writable_by_all(path: Path) -> None:
    path.chmod(0o602)


def corrupt(path: Path) -> None:
    path.write_bytes(dataclass_code.HEADER + b"\x00not marshal data")


def holding_other_types(path: Path) -> None:
    path.write_bytes(dataclass_code.HEADER + marshal.dumps({"def __init__(self): pass": 1}))


def from_another_python(path: Path) -> None:
    data = path.read_bytes()
    other = dataclass_code.HEADER.replace(sys.version.encode(), b"3.99.0 (main) [another compiler]")
    path.write_bytes(other + data[len(dataclass_code.HEADER):])


def truncated(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def another_users(path: Path) -> None:
    if os.geteuid() != 0:
        pytest.skip("giving a file to another user takes root")
    os.chown(path, 65534, 65534)


@pytest.mark.parametrize("spoil", [writable_by_group, writable_by_all, corrupt, holding_other_types,
                                   from_another_python, truncated, another_users],
                         ids=lambda spoil: spoil.__name__.replace("_", " "))
def test_a_file_it_cannot_trust_or_read_is_ignored_and_rewritten_whole_on_save(kept_code, tmp_path, spoil):
    kept_code.install()
    make_classes()
    kept_code.save()
    path = tmp_path / FILE_NAME
    whole = kept_code.read(str(path))
    assert whole
    spoil(path)
    assert kept_code.read(str(path)) == {}
    forget_in_memory(kept_code)
    kept_code.install()
    make_classes()
    assert kept_code.compiled == len(whole)
    kept_code.save()
    assert kept_code.read(str(path)).keys() == whole.keys()
    assert path.stat().st_mode & 0o777 == 0o600 and path.stat().st_uid == os.geteuid()


def test_an_entry_that_is_not_code_is_compiled_again(kept_code, tmp_path):
    kept_code.install()
    make_classes()
    kept_code.save()
    path = tmp_path / FILE_NAME
    texts = kept_code.read(str(path)).keys()
    path.write_bytes(kept_code.HEADER + marshal.dumps(dict.fromkeys(texts, marshal.dumps("not code"))))
    forget_in_memory(kept_code)
    kept_code.install()
    assert behaviour(*make_classes()) and kept_code.compiled == len(texts)


def test_a_folder_where_the_file_should_be_costs_compiling_and_nothing_else(kept_code, tmp_path):
    (tmp_path / FILE_NAME).mkdir()
    assert kept_code.install()
    make_classes()
    assert kept_code.compiled > 0
    kept_code.save()  # (cannot replace a folder: ignored)
    assert (tmp_path / FILE_NAME).is_dir() and [p.name for p in tmp_path.iterdir()] == [FILE_NAME]


def test_over_the_limit_the_file_keeps_only_what_the_saving_process_used(kept_code, tmp_path, monkeypatch):
    kept_code.install()
    make_classes()
    kept_code.save()
    earlier = set(kept_code.read(str(tmp_path / FILE_NAME)))
    forget_in_memory(kept_code)
    kept_code.install()
    dataclasses.make_dataclass("Other", [("other_x", int)])
    used = set(kept_code._new)
    monkeypatch.setattr(kept_code, "LIMIT", len(earlier))
    kept_code.save()
    assert set(kept_code.read(str(tmp_path / FILE_NAME))) == used
    assert used and not used & earlier
