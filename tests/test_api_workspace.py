"""The user level's routes in-process (FastAPI's TestClient, a fake run link over the fake job host):
saving an application and an object's value to the file `pbo hmi FILE` was given, and running the
workspace's row on the run, each refusal answered with its one-line reason.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from pbo_runtime.api.app import create_app
from pbo_runtime.api.link import NoRun
from pbo_runtime.config.loader import check_file, load_subsystem
from pbo_runtime.ipc.control import answer
from pbo_runtime.supervisor.commands import dispatch
from tests.fake_job_host import FakeJobHost, fake_subsystem

TOKEN = "the-token-of-this-test"
BEARER = {"Authorization": f"Bearer {TOKEN}"}
READY = [0.3, -0.5, 0.5, 0.2, 0.4, 0.2]


class FakeRunLink:
    """A unit test's run: verbs served by `commands.dispatch` on a fake job host, as the supervisor answers them."""

    def __init__(self, host: FakeJobHost) -> None:
        self.host = host
        self.requests: list[tuple[str, dict[str, Any]]] = []

    def request(self, command: str, arguments: dict[str, Any], timeout: float) -> dict[str, Any]:
        self.requests.append((command, dict(arguments)))
        return answer(lambda c, a: dispatch(self.host, c, a), command, arguments)


class NoRunLink(FakeRunLink):
    """A unit test's link when no run is alive, as `LiveRunLink` says it."""

    def request(self, command: str, arguments: dict[str, Any], timeout: float) -> dict[str, Any]:
        raise NoRun("no subsystem is running (no live state variable table of yours in /dev/shm): start one with `pbo run FILE`")


@pytest.fixture
def subsystem(tmp_path):
    return fake_subsystem(tmp_path)


@pytest.fixture
def link(subsystem):
    return FakeRunLink(FakeJobHost(subsystem, "pid"))


@pytest.fixture
def client(link, subsystem):
    return TestClient(create_app(link, TOKEN, subsystem.file))


def post(client: TestClient, path: str, body: dict):
    return client.post(f"/api/workspace/{path}", json=body, headers=BEARER)


def step(name: str, obj: str | None = None) -> dict:
    return {"name": name, "object": obj}


def test_the_routes_need_the_token(client):
    assert client.post("/api/workspace/run", json={"row": [step("hold")]}).status_code == 401


def test_an_incomplete_application_is_saved_and_comes_back_as_an_action_requiring_an_object(client, subsystem):
    reply = post(client, "applications", {"name": "approach", "row": [step("reach"), step("hold")]})
    assert reply.status_code == 200, reply.text
    body = reply.json()
    assert body["message"].startswith(f"application 'approach' saved to {subsystem.file}, incomplete (1 gap(s))")
    assert [w.split("warning[")[1][:4] for w in body["warnings"]] == ["W701"]
    icon = body["dictionary"]["applications"]["approach"]
    assert icon["class"] == "action_requiring_object" and icon["edges"]["right"] == {"shape": "notch",
                                                                                     "object_type": "joint_position"}
    assert check_file(subsystem.file).ok


@pytest.mark.parametrize("body, refusal", [
    ({"name": "tour", "row": [step("hold")]}, r"application 'tour' exists in .*: choose another name, or replace it"),
    ({"name": "2x", "row": [step("hold")]}, r"an application's name is a letter"),
    ({"name": "x", "row": []}, r"the workspace is empty"),
    ({"name": "x", "row": [step("hold", "ready")]}, r"the icons do not interlock: step 1: 'hold' takes no object"),
])
def test_a_save_that_is_wrong_is_refused_with_its_reason_and_the_file_kept(client, subsystem, body, refusal):
    before = Path(subsystem.file).read_text()
    reply = post(client, "applications", body)
    assert reply.status_code == 400
    assert reply.json()["ok"] is False
    assert re.search(refusal, reply.json()["error"]), reply.json()["error"]
    assert Path(subsystem.file).read_text() == before


def test_an_objects_value_is_saved_to_the_file_and_the_dictionary_shows_it(client, subsystem):
    reply = post(client, "objects", {"name": "ready", "value": [0, 0.1, 0.2, 0.3, 0.4, 0.5]})
    assert reply.status_code == 200, reply.text
    assert reply.json()["dictionary"]["objects"]["ready"]["value"] == [0, 0.1, 0.2, 0.3, 0.4, 0.5]
    assert load_subsystem(subsystem.file).objects["ready"].value.tolist() == [0, 0.1, 0.2, 0.3, 0.4, 0.5]


def test_an_objects_value_of_the_wrong_shape_is_refused_in_one_line(client):
    reply = post(client, "objects", {"name": "ready", "value": [1, 2]})
    assert reply.status_code == 400
    error = reply.json()["error"]
    assert "object 'ready' (type joint_position)" in error and "\n" not in error


def test_the_row_runs_on_the_run_with_its_objects_written_out(client, link):
    reply = post(client, "run", {"name": "workspace", "row": [step("reach", "ready"), step("hold")]})
    assert reply.status_code == 200, reply.text
    assert reply.json()["jobs"] == ["reach", "hold"]
    assert link.requests[-1] == ("app", {"application": "workspace", "steps": [{"reach": {"q_d": READY}}, "hold"]})
    assert link.host.started_applications == ["workspace"]


def test_a_row_with_a_gap_is_refused_a_run_before_the_run_is_asked(client, link):
    reply = post(client, "run", {"name": "workspace", "row": [step("reach"), step("hold")]})
    assert reply.status_code == 400
    assert reply.json()["error"] == ("the application has 1 gap and cannot run: step 1 'reach' needs an object of type "
                                     "joint_position; drop an object of that type on each gap")
    assert link.requests == []


def test_a_run_with_no_run_attached_says_so(subsystem):
    client = TestClient(create_app(NoRunLink(FakeJobHost(subsystem, "pid")), TOKEN, subsystem.file))
    reply = post(client, "run", {"row": [step("hold")]})
    assert reply.status_code == 404
    assert reply.json()["error"].startswith("no run is attached to run it on: no subsystem is running")


def test_a_run_while_an_application_runs_is_refused_by_the_run(client, link):
    link.host.application = "tour"
    reply = post(client, "run", {"row": [step("hold")]})
    assert reply.status_code == 409
    assert reply.json()["error"].startswith("application 'tour' is running its jobs")
