"""An application file's routes in-process (FastAPI's TestClient): its stages as the workspace shows them,
`run:` written back only when each arm's row is its own subsystem's and the file then checks clean, and
each refusal answered with its one-line reason, the file left as it was.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from pbo_runtime.api.app import create_app
from pbo_runtime.api.link import NoRun
from pbo_runtime.config.application import check_application
from tests.support import DEMO, REPO

TOKEN = "the-token-of-this-test"
BEARER = {"Authorization": f"Bearer {TOKEN}"}


class NoRunLink:
    """A unit test's link when no run is alive: the application's routes never ask it."""

    def request(self, command: str, arguments: dict[str, Any], timeout: float) -> dict[str, Any]:
        raise NoRun("no subsystem is running")


@pytest.fixture
def file(tmp_path) -> Path:
    copy = tmp_path / "two_arms.yaml"
    shutil.copy(REPO / "configs" / "two_arms.yaml", copy)
    return copy


@pytest.fixture
def client(file):
    return TestClient(create_app(NoRunLink(), TOKEN, str(file)))  # type: ignore[arg-type]


def reach(obj: str, subsystem: str | None = None) -> dict:
    return {"name": "reach", "object": obj, **({"subsystem": subsystem} if subsystem else {})}


def stages(*extra: dict) -> dict:
    """The shipped file's three stages as the page sends them, and `extra` after them."""
    shipped = [{"arms": {"left": [reach("ready", "left")], "right": [reach("ready", "right")]}},
               {"arms": {"left": [{"name": "wave", "object": None, "subsystem": "left"}], "right": []}},
               {"arms": {"left": [{"kind": "if", "condition": "abs(q_m[0]) > 0.01", "rows": [[reach("home")], []]}],
                         "right": [reach("home")]}}]
    return {"stages": [*shipped, *extra]}


def test_the_routes_need_the_token(client):
    assert client.get("/api/application").status_code == 401


def test_the_workspace_has_each_subsystems_dictionary_and_the_files_stages(client):
    reply = client.get("/api/application", headers=BEARER)
    assert reply.status_code == 200, reply.text
    body = reply.json()
    assert {key: sub["name"] for key, sub in body["subsystems"].items()} == {"left": "two_arms_left", "right": "two_arms_right"}
    assert list(body["subsystems"]["left"]["dictionary"]["applications"]) == ["wave"]
    assert [sorted(stage["arms"]) for stage in body["stages"]] == [["left", "right"], ["left"], ["left", "right"]]
    assert body["stages"][1]["arms"]["left"]["app"] == "wave"
    assert body["stages"][2]["arms"]["left"]["steps"][0]["decision"]["kind"] == "if"
    assert body["run"] == {"started": False, "running": False, "pid": None, "exit": None, "clock": "",
                           "stages_done": {}, "lines": []}


def test_a_new_stage_is_written_to_run_and_the_stages_as_they_were_keep_their_lines(client, file):
    reply = client.post("/api/application/stages", headers=BEARER,
                        json=stages({"arms": {"left": [reach("ready", "left")], "right": []}}))
    assert reply.status_code == 200, reply.text
    assert reply.json()["message"] == "run: saved to two_arms.yaml, 4 stage(s); pbo check finds no error"
    text = file.read_text()
    assert text.endswith("      right: [reach: home]\n  - parallel:\n      left: [reach: ready]\n")
    assert "{left: {app: wave}}                              # the left arm waves, the right one holds" in text
    assert len(check_application(file).application.stages) == 4


@pytest.mark.parametrize("extra, refusal", [
    ({"arms": {"right": [reach("ready", "left")]}},
     r"stage 4 \(parallel\), arm 'right': step 1 'reach' is of subsystem 'left': an arm runs its own subsystem's jobs"),
    ({"arms": {"right": [{"kind": "repeat", "times": 2, "rows": [[reach("home", "left")]]}]}},
     r"arm 'right', step 1 \(repeat, repeat\): step 1 'reach' is of subsystem 'left'"),
    ({"arms": {"right": [{"name": "wave", "object": None}]}},
     r"arm 'right': the icons do not interlock: step 1: 'wave' is no job, application or object of this subsystem"),
    ({"arms": {"right": [reach(None)]}}, r"arm 'right': the application has 1 gap and cannot run"),
    ({"arms": {"left": [], "right": []}}, r"stage 4 \(parallel\) has no step in any arm"),
    ({"arms": {"middle": [reach("home")]}}, r"stage 4 \(parallel\) has an arm 'middle', which is no subsystem of"),
    # each arm interlocks, but the file would not check: the condition names a variable the subsystem does not have
    ({"arms": {"left": [{"kind": "if", "condition": "q_nowhere[0] > 0", "rows": [[reach("home")], []]}]}},
     r"^not saved: .*two_arms.yaml would have 1 error, the first: .*error\[E813\]: run: stage 4: the steps of subsystem "
     r"'left' do not interlock: .*q_nowhere"),
])
def test_a_stage_that_is_wrong_is_refused_with_its_reason_and_the_file_kept(client, file, extra, refusal):
    before = file.read_text()
    reply = client.post("/api/application/stages", headers=BEARER, json=stages(extra))
    assert reply.status_code == 400
    assert re.search(refusal, reply.json()["error"]), reply.json()["error"]
    assert "\n" not in reply.json()["error"]
    assert file.read_text() == before
    assert sorted(p.name for p in file.parent.iterdir()) == ["two_arms.yaml"]  # no draft left beside it


def test_a_run_on_a_clock_that_does_not_exist_is_refused(client):
    reply = client.post("/api/application/run", headers=BEARER, json={"clock": "fast"})
    assert reply.status_code == 400
    assert reply.json()["error"] == "not started: clock must be one of real, sim, got 'fast'"


def test_a_status_stream_of_a_subsystem_the_file_does_not_have_is_refused(client):
    assert client.get("/api/application", headers=BEARER).status_code == 200
    with client.websocket_connect("/api/streams/status?subsystem=puma", headers=BEARER) as socket:
        message = socket.receive_json()
    assert message == {"ok": False, "error": "no subsystem 'puma' in the application file served "
                                             "(subsystems: two_arms_left, two_arms_right)"}


def test_a_subsystem_file_has_no_application_routes(tmp_path):
    copy = tmp_path / "pid_joint.yaml"
    shutil.copy(DEMO, copy)
    reply = TestClient(create_app(NoRunLink(), TOKEN, str(copy))).get("/api/application", headers=BEARER)  # type: ignore[arg-type]
    assert reply.status_code == 404
    assert reply.json()["error"].startswith("pbo hmi was given no application file")


def test_a_run_that_picks_each_subsystems_application_is_not_overwritten_by_stages(tmp_path):
    for name in ("leader_follower.yaml", "leader.yaml", "follower.yaml"):
        shutil.copy(REPO / "configs" / name, tmp_path / name)
    file = tmp_path / "leader_follower.yaml"
    before = file.read_text()
    client = TestClient(create_app(NoRunLink(), TOKEN, str(file)))  # type: ignore[arg-type]
    assert client.get("/api/application", headers=BEARER).json()["stages"] == []
    reply = client.post("/api/application/stages", headers=BEARER,
                        json={"stages": [{"arms": {"operator": [{"name": "tour", "object": None}]}}]})
    assert reply.status_code == 400
    assert "picks each subsystem's configuration or application" in reply.json()["error"]
    assert file.read_text() == before


@pytest.mark.multiprocess
def test_run_starts_pbo_run_of_the_file_and_every_subsystem_does_every_stage(client, file):
    reply = client.post("/api/application/run", headers=BEARER, json={"clock": "sim"})
    assert reply.status_code == 200, reply.text
    assert reply.json()["message"].startswith("pbo run two_arms.yaml --clock sim started (pid ")
    again = client.post("/api/application/run", headers=BEARER, json={"clock": "sim"})
    assert again.status_code == 409 and "the application runs already" in again.json()["error"]
    assert client.app.state.application_run.wait(timeout=600) == 0  # a net for a hang, never a timing
    state = client.get("/api/application/run", headers=BEARER).json()["run"]
    assert (state["running"], state["exit"], state["stages_done"]) == (False, 0, {"left": 3, "right": 3})
    assert "[left] pbo: every stage is done" in state["lines"] and "[right] pbo: every stage is done" in state["lines"]
    assert [p.name[:9] for p in (file.parent / "runs").iterdir()] == ["two_arms-"]  # in the served folder
