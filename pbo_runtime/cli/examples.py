"""`pbo examples [DIR]`: copy the example subsystem files, and the JSON Schema they name, out of the package.

They ship inside the package, in `example_configs/` beside this file. In a checkout that folder is a
link to the repository's `configs/`, the one place they are edited; a wheel holds a copy of every
file under it. Copied out, each file keeps its place relative to the others, so a config's
`$schema=pbo-subsystem.schema.json` comment, an application's subsystem files and any file a config
names resolve in the copy as they do in the repository.

A file already in DIR that equals the shipped one is left as it is; one that differs (the user's
edits) is never overwritten without `force`, and then nothing at all is written.
"""

from __future__ import annotations

import argparse
import shlex
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from pbo_runtime.cli.exits import EXIT_CONFIG, EXIT_OK

if TYPE_CHECKING:
    from rich.console import Console

EXAMPLES = Path(__file__).resolve().parent / "example_configs"


class ExamplesRefused(Exception):
    """The examples cannot be copied into the folder asked for; the message says why and what to do."""


@dataclass(frozen=True)
class Copied:
    """What `copy_examples` did, by path relative to the folder: written anew, overwritten, already equal."""

    folder: Path
    written: tuple[str, ...]
    overwritten: tuple[str, ...]
    unchanged: tuple[str, ...]


def copy(args: argparse.Namespace, console: Console, errors: Console) -> int:
    """`pbo examples [DIR]`."""
    try:
        copied = copy_examples(args.dir, force=args.force)
    except ExamplesRefused as exc:
        errors.print(f"error: {exc}", markup=False)
        return EXIT_CONFIG
    console.print("\n".join(summary(copied)), markup=False, soft_wrap=True)
    return EXIT_OK


def shipped_files(examples: Path = EXAMPLES) -> list[str]:
    """Every file of the shipped examples, as a POSIX path relative to their folder, sorted."""
    return sorted(path.relative_to(examples).as_posix() for path in examples.rglob("*")
                  if path.is_file() and "__pycache__" not in path.parts)


def copy_examples(folder: Path, force: bool = False, examples: Path = EXAMPLES) -> Copied:
    """Copy every shipped file into `folder` (made if missing); refuse before writing anything if a
    file there differs from its shipped version, unless `force`."""
    if folder.exists() and not folder.is_dir():
        raise ExamplesRefused(f"{folder} is a file, not a folder: give a folder for the examples, e.g. pbo examples my-examples")
    files = shipped_files(examples)
    if not files:  # only a broken install gets here: the package data did not make it into the wheel
        raise ExamplesRefused(f"no examples in {examples}: the installed package lacks its package data; reinstall pbo-runtime")
    new, differ, same = [], [], []
    for name in files:
        target = folder / name
        if not target.exists():
            new.append(name)
        elif target.is_file() and target.read_bytes() == (examples / name).read_bytes():
            same.append(name)
        else:
            differ.append(name)
    if differ and not force:
        shown = ", ".join(differ[:3]) + (f" and {len(differ) - 3} more" if len(differ) > 3 else "")
        verb = "differs" if len(differ) == 1 else "differ"
        raise ExamplesRefused(f"{folder}: {_files(len(differ))} {verb} from the shipped examples ({shown}); nothing written: "
                              "--force overwrites them, or give another folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ExamplesRefused(f"cannot make the folder {folder}: {exc.strerror or exc}: give a folder you can write to") from exc
    for name in (*new, *differ):
        target = folder / name
        try:
            if target.is_dir():  # a folder where a shipped file goes: only --force gets here
                shutil.rmtree(target)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(examples / name, target)
        except OSError as exc:
            raise ExamplesRefused(f"cannot write {target}: {exc.strerror or exc}: give a folder you can write to") from exc
    return Copied(folder, tuple(new), tuple(differ), tuple(same))


def summary(copied: Copied) -> list[str]:
    """What was written where, one line per file, then the commands to try on the copy."""
    lines = []
    if copied.written or copied.overwritten:
        lines.append(f"wrote {_files(len(copied.written) + len(copied.overwritten))} into {copied.folder}:")
        lines.extend(f"  {name}" for name in copied.written)
        lines.extend(f"  {name} (overwritten)" for name in copied.overwritten)
    if copied.unchanged:
        lines.append(f"left {_files(len(copied.unchanged))} there as they were: equal to the shipped ones")
    names = (*copied.written, *copied.overwritten, *copied.unchanged)
    demo = "pid_joint.yaml" if "pid_joint.yaml" in names else next((n for n in sorted(names) if n.endswith(".yaml")), None)
    if demo is not None:
        path = shlex.quote(str(copied.folder / demo))
        lines.append(f"next: pbo check {path}; pbo run {path} (each file's comments say what it shows)")
    return lines


def _files(count: int) -> str:
    return f"{count} file{'' if count == 1 else 's'}"


def missing_example_hint(given: str, examples: Path = EXAMPLES) -> str | None:
    """For a file that is not there but names a shipped example: where to get it."""
    path = Path(given)
    if path.exists() or path.name not in shipped_files(examples):
        return None
    return (f"hint: '{path.name}' is a shipped example: `pbo examples` copies them into ./pbo-examples "
            f"(then: pbo ... pbo-examples/{path.name}); in a checkout it is configs/{path.name}")
