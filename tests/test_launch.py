"""An RTPU's launch description: what the supervisor writes is what `python -m rtpu` reads back."""

from dataclasses import replace

import pytest

from pbo_runtime.links.run_link import RunLink
from pbo_runtime.supervisor.launch import RtpuLaunch

FULL = RtpuLaunch("configs/demo.yaml", "123-abc", "rtpu1", epoch=12.5, spin=0.0002, fifo=True, clock="sim",
                  tick=0.002, ring=("plant", "rtpu0", "rtpu1"), out="/tmp/out", configuration="pid",
                  application="pick", links={"cmd": RunLink("message", "shm", "float64", (3,), 4, shm_name="/pbo.a.msg-cmd")},
                  live="/tmp/live",
                  live_now=2, restarted=True, parent=4242)


@pytest.mark.parametrize("launch", [RtpuLaunch("a.yaml", "1-2", "rtpu0"), FULL], ids=["defaults", "every field"])
def test_a_launch_reads_back_as_written(launch):
    assert RtpuLaunch.parse(launch.to_argv()) == launch


def test_a_restart_changes_fields_not_strings():
    first = RtpuLaunch("a.yaml", "1-2", "rtpu0", live="/tmp/live")
    again = replace(first, restarted=True, live_now=3)
    assert "--restarted" not in first.to_argv() and "--live-now" not in first.to_argv()
    assert RtpuLaunch.parse(again.to_argv()) == again
    assert replace(again, live_now=0).to_argv().count("--live-now") == 0  # restarted from the file again


def test_the_real_clock_says_nothing_of_ticks():
    argv = RtpuLaunch("a.yaml", "1-2", "rtpu0").to_argv()
    assert "--clock" not in argv and "--ring" not in argv


def test_a_launch_without_its_run_is_refused(capsys):
    with pytest.raises(SystemExit):
        RtpuLaunch.parse(["a.yaml", "--rtpu", "rtpu0"])
    assert "--run-id" in capsys.readouterr().err
