"""The engineer level's routes in-process (FastAPI's TestClient): the canvas a file starts from, the
canvas checked with placement, and Save as job writing the file pbo hmi was given, never another.
"""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient

from pbo_runtime.api.app import create_app
from pbo_runtime.api.link import NoRun
from pbo_runtime.config.loader import check_file
from tests.support import FIGURE_8_CANVAS, REPO, canvas_base_file

TOKEN = "the-token-of-this-test"
BEARER = {"Authorization": f"Bearer {TOKEN}"}


class NoRunLink:
    """A unit test's link when no run is alive."""

    def request(self, command: str, arguments: dict[str, Any], timeout: float) -> dict[str, Any]:
        raise NoRun("no subsystem is running: start one with `pbo run FILE`")

    def open_table(self) -> Any:
        raise NoRun("no subsystem is running")

    def runs(self) -> list[dict[str, Any]]:
        return []


def client_for(file: str | None) -> TestClient:
    return TestClient(create_app(NoRunLink(), TOKEN, file), headers=BEARER)  # type: ignore[arg-type]


def test_the_canvas_starts_from_the_files_configurations():
    reply = client_for(str(REPO / "configs" / "pid_joint.yaml")).get("/api/canvas").json()
    assert reply["ok"] and reply["rtpus"] == ["rtpu0", "rtpu1"]
    assert reply["configurations"]["joint_pid"] == ["robot", "traj", "pid", "logger"]
    assert reply["tasks"]["logger"]["params"]["variables"] == "[q_m, q_r, tau_u]"


def test_the_canvas_is_checked_with_its_diagnostics_on_blocks_and_the_placement_of_the_lexicon(tmp_path):
    client = client_for(str(canvas_base_file(tmp_path)))
    second = {"name": "inv", "module": "inverse_dynamics", "fields": {"rtpu": "rtpu0", "period": "1 ms"}}
    clean = client.post("/api/canvas/check", json={"tasks": FIGURE_8_CANVAS, "configuration": "joint_pid"}).json()
    assert clean["ok"] and clean["valid"] and clean["configuration"] == "joint_pid"
    assert {v["module"]: v.get("code") for v in clean["placement"]["modules"]}["inverse_dynamics"] == "E401"
    broken = client.post("/api/canvas/check", json={"tasks": [*FIGURE_8_CANVAS, second]}).json()
    assert [(d["code"], d["task"], d["port"]) for d in broken["diagnostics"] if d["code"] == "E401"] == [("E401", "inv", "tau")]


@pytest.mark.parametrize(("body", "status", "says"), [
    ({"tasks": "x"}, 400, "body.tasks: Input should be a valid list"),
    ({"tasks": [{"name": "a"}]}, 400, "task 'a': its module must be a module's name"),
    ({"tasks": [], "configuration": "no way"}, 400, "a configuration's name is an identifier"),
    ({}, 400, "bad parameters"),
])
def test_a_malformed_canvas_is_refused_in_one_line(tmp_path, body, status, says):
    reply = client_for(str(canvas_base_file(tmp_path))).post("/api/canvas/check", json=body)
    assert reply.status_code == status and says in reply.json()["error"]
    assert "\n" not in reply.json()["error"]


def test_without_a_file_the_canvas_routes_say_how_to_give_one():
    reply = client_for(None).post("/api/canvas/check", json={"tasks": []})
    assert reply.status_code == 404 and "pbo hmi FILE" in reply.json()["error"]


def test_save_as_job_writes_the_file_pbo_hmi_was_given_and_pbo_check_lists_the_job(tmp_path):
    path = canvas_base_file(tmp_path)
    client = client_for(str(path))
    reply = client.post("/api/canvas/job", json={"name": "reach", "tasks": FIGURE_8_CANVAS, "file": "/tmp/elsewhere.yaml"}).json()
    assert reply["ok"] and reply["file"] == str(path) and reply["class"] == "action_requiring_object"
    assert "reach" in check_file(path).subsystem.jobs
    again = client.post("/api/canvas/job", json={"name": "reach", "tasks": FIGURE_8_CANVAS})
    assert again.status_code == 409 and again.json()["error"] == "the file has a job 'reach' already: choose another name"
