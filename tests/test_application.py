"""Applications of several subsystems (TR §5): the file's checks, and two arms joined by a link."""

from __future__ import annotations

import json
import os
import subprocess

import numpy as np
import pytest

from pbo_runtime._application import check_application, is_application_file
from tests.conftest import REPO
from tests.test_end_to_end import PBO, assert_nothing_left

APP = REPO / "configs" / "leader_follower.yaml"


def write_app(tmp_path, links: str = "  arm_state: {type: float64, shape: [6], transport: shm}\n",
              follower: str | None = None, extra: str = "") -> str:
    """The shipped application, copied beside its subsystems so each can be changed."""
    (tmp_path / "leader.yaml").write_text((REPO / "configs" / "leader.yaml").read_text())
    (tmp_path / "follower.yaml").write_text(follower or (REPO / "configs" / "follower.yaml").read_text())
    path = tmp_path / "app.yaml"
    path.write_text("application: pair\nsubsystems:\n  leader: leader.yaml\n  follower: follower.yaml\n"
                    f"{extra}links:\n{links}")
    return str(path)


def codes(result) -> list[str]:
    return [e.code for e in result.errors]


def test_the_shipped_application_checks_clean_and_names_each_link_end():
    result = check_application(APP)
    assert result.ok, [e.format() for e in result.errors]
    link = result.application.links["arm_state"]
    assert (link.sender, link.receiver) == (("leader", "send"), ("follower", "receive"))
    assert is_application_file(APP) and not is_application_file(REPO / "configs" / "leader.yaml")


def test_a_task_naming_an_undeclared_link_is_located_on_the_task(tmp_path):
    follower = (REPO / "configs" / "follower.yaml").read_text().replace("params: {link: arm_state}", "params: {link: arm_stat}")
    result = check_application(write_app(tmp_path, follower=follower))
    assert "E804" in codes(result)
    error = next(e for e in result.errors if e.code == "E804")
    assert error.file.endswith("follower.yaml") and error.line > 0
    assert "uses link 'arm_stat', which the application does not declare" in error.message


def test_a_link_without_a_receiver_is_an_error_with_a_hint(tmp_path):
    result = check_application(write_app(tmp_path, links="  arm_state: {type: float64, shape: [6]}\n"
                                                         "  spare: {type: float64, shape: [6]}\n"))
    errors = [e for e in result.errors if e.code == "E805"]
    assert {e.message for e in errors} == {"link 'spare' has no link_sender task", "link 'spare' has no link_receiver task"}
    assert all(e.line == 7 for e in errors) and "module: link_receiver" in errors[1].hint + errors[0].hint


def test_a_variable_of_another_shape_than_its_link_is_refused(tmp_path):
    result = check_application(write_app(tmp_path, links="  arm_state: {type: float64, shape: [7]}\n"))
    assert codes(result).count("E806") == 2
    assert "carries float64 [7]" in result.errors[0].message


def test_an_unknown_transport_and_a_missing_subsystem_file_are_reported_together(tmp_path):
    path = write_app(tmp_path, links="  arm_state: {type: float64, shape: [6], transport: carrier-pigeon}\n")
    text = open(path).read().replace("follower: follower.yaml", "follower: nowhere.yaml")
    open(path, "w").write(text)
    result = check_application(path)
    assert set(codes(result)) == {"E802", "E803"}
    assert any("unknown transport 'carrier-pigeon'" in e.message and "shm, zenoh" in e.hint for e in result.errors)
    assert any("no file 'nowhere.yaml'" in e.message for e in result.errors)


def test_an_error_in_a_subsystem_file_is_reported_with_its_own_location(tmp_path):
    follower = (REPO / "configs" / "follower.yaml").read_text().replace("period: 2 ms, params: {link", "period: 2 fortnights, params: {link")
    result = check_application(write_app(tmp_path, follower=follower))
    assert result.errors and all(e.file.endswith("follower.yaml") for e in result.errors)


def test_pbo_check_on_an_application_prints_every_link(tmp_path):
    done = subprocess.run([*PBO, "check", str(APP)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "link arm_state: leader.send -> follower.receive (float64 [6], shm)" in done.stdout


def test_a_subsystem_run_alone_says_which_link_it_lacks(tmp_path):
    done = subprocess.run([*PBO, "run", str(REPO / "configs" / "follower.yaml"), "--no-live", "--duration", "1"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert "opens link 'arm_state', but the application provides no such link" in done.stderr
    assert "pbo run APP.yaml" in done.stderr


@pytest.mark.multiprocess
def test_the_follower_arm_tracks_the_leader_through_a_shared_memory_link(tmp_path):
    done = subprocess.run([*PBO, "run", str(APP), "--duration", "3", "--out", str(tmp_path / "out")], cwd=tmp_path,
                          capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "[leader] pbo: configuration 'lead' is on" in done.stdout and "[follower] run summary" in done.stdout
    leader = np.load(tmp_path / "out" / "leader" / "leader.npz")
    follower = np.load(tmp_path / "out" / "follower" / "follower.npz")
    assert np.max(np.abs(leader["q_m"][-1] - np.array([0.3, -0.5, 0.5, 0.2, 0.4, 0.2]))) < 0.01  # the leader reached its goal
    assert np.max(np.abs(follower["q_d"][-1] - leader["q_m"][-1])) < 0.01  # the link carried it
    assert np.max(np.abs(follower["q_m"][-1] - leader["q_m"][-1])) < 0.01  # and the follower got there too
    lost, reused, age = follower["link_counts"][-1]
    assert lost >= 0 and reused >= 0 and age >= 0  # no bound: the leader may stop before the follower's last cycles
    for key in ("leader", "follower"):
        assert_nothing_left(json.loads((tmp_path / "out" / key / "report.json").read_text()))
    assert [n for n in os.listdir("/dev/shm") if "pbo.pair." in n or "pbo.leader_follower." in n] == []


@pytest.mark.multiprocess
def test_the_same_application_runs_over_zenoh_changed_only_in_yaml(tmp_path):
    pytest.importorskip("zenoh")
    path = write_app(tmp_path, links="  arm_state: {type: float64, shape: [6], transport: zenoh}\n")
    done = subprocess.run([*PBO, "run", path, "--duration", "3", "--out", str(tmp_path / "out")], cwd=tmp_path,
                          capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "link 'arm_state': leader.send -> follower.receive (float64 [6], zenoh)" in done.stdout
    leader = np.load(tmp_path / "out" / "leader" / "leader.npz")
    follower = np.load(tmp_path / "out" / "follower" / "follower.npz")
    assert np.max(np.abs(follower["q_d"][-1] - leader["q_m"][-1])) < 0.01
    assert np.max(np.abs(follower["q_m"][-1] - leader["q_m"][-1])) < 0.01
