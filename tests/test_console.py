"""The CLI's consoles (`cli.console`): off a terminal a run's lines are written as they are, before
rich is imported; on a terminal, or where a variable makes rich style a pipe, rich writes them."""

from __future__ import annotations

import io
import os
import pty
import subprocess
import sys

import pytest

from pbo_runtime.cli.console import WIDTH_OFF_TERMINAL, LazyConsole
from tests.support import REPO

SAY = """
import sys
from pbo_runtime.cli.console import LazyConsole
from pbo_runtime.cli.running import _sayer
_sayer(LazyConsole())("x [y] :smile:")
print("rich imported:", "rich" in sys.modules)
"""


def _said(stdout: int | None = subprocess.PIPE, **variables: str) -> str:
    """What SAY printed, in a fresh interpreter (its stdout a pipe, or the given terminal)."""
    env = {key: value for key, value in os.environ.items() if key not in ("FORCE_COLOR", "TTY_COMPATIBLE")}
    done = subprocess.run([sys.executable, "-c", SAY], cwd=REPO, env={**env, **variables}, stdout=stdout,
                          stderr=subprocess.PIPE, text=True, check=True, timeout=60)
    return done.stdout


@pytest.mark.multiprocess
def test_a_runs_lines_off_a_terminal_are_written_as_they_are_without_importing_rich():
    assert _said() == "pbo: x [y] :smile:\nrich imported: False\n"


@pytest.mark.multiprocess
def test_a_runs_lines_on_a_terminal_are_styled_by_rich():
    leader, follower = pty.openpty()
    try:
        _said(stdout=follower)
        os.close(follower)
        follower = -1
        said = b""
        while True:
            try:
                chunk = os.read(leader, 4096)
            except OSError:  # (the terminal's other end closed: all was read)
                break
            if not chunk:
                break
            said += chunk
    finally:
        os.close(leader)
        if follower >= 0:
            os.close(follower)
    text = said.decode()
    assert "\x1b[2mpbo:\x1b[0m x [y] :smile:" in text  # dim, the brackets and the colons kept as written
    assert "rich imported: True" in text


@pytest.mark.multiprocess
@pytest.mark.parametrize("variable", ["FORCE_COLOR", "TTY_COMPATIBLE"])
def test_a_variable_that_makes_rich_treat_a_pipe_as_a_terminal_sends_the_lines_through_rich(variable):
    said = _said(**{variable: "1"})
    assert "rich imported: True" in said
    assert "pbo:" in said and "x [y] :smile:" in said


@pytest.mark.multiprocess
def test_importing_the_run_verb_imports_no_rich():
    check = "import sys, pbo_runtime.cli.running; print('rich' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", check], cwd=REPO, capture_output=True, text=True, check=True, timeout=60)
    assert done.stdout == "False\n"


def test_off_a_terminal_both_consoles_are_wide_for_logs_and_print_emoji_codes_as_written(monkeypatch):
    monkeypatch.delenv("FORCE_COLOR", raising=False)
    monkeypatch.delenv("TTY_COMPATIBLE", raising=False)
    out, err = io.StringIO(), io.StringIO()
    monkeypatch.setattr(sys, "stdout", out)
    monkeypatch.setattr(sys, "stderr", err)
    console = LazyConsole()
    errors = LazyConsole(stderr=True, width_from=console)
    assert not console.is_terminal
    console.print(":smile: [b]x[/b]")
    errors.print("error: :warning:", markup=False)
    assert console.made.width == errors.made.width == WIDTH_OFF_TERMINAL
    assert out.getvalue() == ":smile: x\n" and err.getvalue() == "error: :warning:\n"


def test_once_rich_is_made_the_lines_go_through_it():
    console = LazyConsole()
    console.made  # noqa: B018  (made, as a summary or an error would have it)
    assert not console.write_plainly("pbo: x")
