"""The one way an edit reaches a subsystem file: written beside it, checked, then moved over it.

The new text is written to a draft in the file's folder, so its includes and the paths it names
resolve as the file's will, and checked by `pbo check`'s own loader there. Only a draft that checks
clean replaces the file, in one rename with the file's mode: a reader sees the old file or the
whole new one, and a refused or failed write leaves the file as it was and no draft behind.
`pbo save`, the canvas's jobs and the workspace's applications and objects all write through here,
and so does an application file's `run:` from the HMI (checked as `pbo check APP.yaml` checks it).
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable
from typing import TypeVar

from pbo_runtime.config.application import ApplicationCheck, check_application
from pbo_runtime.config.loader import CheckResult, check_file
from pbo_runtime.errors import ConfigError, PboError

Checked = TypeVar("Checked", CheckResult, ApplicationCheck)

DRAFT_ATTEMPTS = 8  # names to try for the draft before giving up: another writer's draft may hold one


class WriteRefused(PboError):
    """The file was left as it was: its new text does not check clean (`errors`, the first located in the
    file in the message), or the file could not be written (the message names it and the system's reason)."""

    def __init__(self, message: str, errors: list[ConfigError] | None = None, first: str = "") -> None:
        super().__init__(message)
        self.errors = list(errors or [])
        self.first = first  # the first error's first line, located in the file rather than the draft


def write_checked(file: str, text: str, even_with_errors: bool = False) -> CheckResult:
    """Replace `file` (or create it) with `text` if `text` checks clean; the draft's check (its locations name
    the draft, which is gone). `even_with_errors` writes it whatever the check says: `pbo save`, whose reply
    warns instead. WriteRefused says why the file is as it was."""
    return _replace_checked(file, text, check_file, lambda result: result.subsystem is not None, even_with_errors)


def write_checked_application(file: str, text: str) -> ApplicationCheck:
    """The same for an application file: `text` replaces `file` only if `pbo check` of it (every subsystem, link
    and stage) has no error."""
    return _replace_checked(file, text, check_application, lambda result: result.application is not None)


def _replace_checked(file: str, text: str, check: Callable[[str], Checked], loads: Callable[[Checked], bool],
                     even_with_errors: bool = False) -> Checked:
    folder, base = os.path.split(os.path.abspath(file))
    mode = _mode_of(file)
    draft, handle = _new_draft(file, folder, base)
    try:
        with os.fdopen(handle, "w", encoding="utf-8") as stream:
            stream.write(text)
        result = check(draft)
        if not even_with_errors and (result.errors or not loads(result)):
            first = result.errors[0].format().splitlines()[0].replace(draft, file) if result.errors else "it does not load"
            count = f"{len(result.errors)} error" + ("" if len(result.errors) == 1 else "s")
            raise WriteRefused(f"not saved: {file} would have {count}, the first: {first}", result.errors, first)
        if mode is not None:
            os.chmod(draft, mode)
        os.replace(draft, file)
    except OSError as exc:
        raise WriteRefused(f"cannot write {file}: {exc.strerror or exc}") from None
    finally:
        if os.path.lexists(draft):
            os.unlink(draft)
    return result


def _mode_of(file: str) -> int | None:
    """The permission bits of the file the draft replaces; None for a new file (the draft's, from the umask)."""
    try:
        return os.stat(file).st_mode & 0o777
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise WriteRefused(f"cannot write {file}: {exc.strerror or exc}") from None


def _new_draft(file: str, folder: str, base: str) -> tuple[str, int]:
    """A new draft beside `file` and its open descriptor; created with the mode a new file gets (0666 less the umask)."""
    for _ in range(DRAFT_ATTEMPTS):
        draft = os.path.join(folder, f".{base}.{secrets.token_hex(4)}.draft.yaml")
        try:
            return draft, os.open(draft, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        except OSError as exc:
            raise WriteRefused(f"cannot write beside {file}: {exc.strerror or exc}") from None
    raise WriteRefused(f"cannot write beside {file}: {DRAFT_ATTEMPTS} draft names in {folder} were taken")
