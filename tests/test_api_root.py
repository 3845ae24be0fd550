"""The API's walls, in-process (FastAPI's TestClient): one folder it reads and writes, limits on what a
request sends, no 500 for bad input, one logged line for a bug, and no listening beyond loopback
unless asked.

The run behind the app is a unit test's fake link (`tests.fake_job_host.FakeRunLink`, verbs answered by
the command table's dispatch on a fake job host). A file planted outside the served folder must stay
unchanged and unseen whatever a request names.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from pbo_runtime.api import files, guard
from pbo_runtime.api.app import create_app
from pbo_runtime.api.link import NoRun
from pbo_runtime.api.server import is_loopback, serve
from pbo_runtime.api.verbs import FILE_ARGUMENTS
from pbo_runtime.config.loader import check_file
from pbo_runtime.supervisor.commands import VERBS
from tests.fake_job_host import FakeJobHost, FakeRunLink, fake_subsystem

TOKEN = "the-token-of-this-test"
BEARER = {"Authorization": f"Bearer {TOKEN}"}
SECRET = "planted-outside: the-content-no-answer-may-show\n"


class NoRunLink(FakeRunLink):
    """A unit test's link when no run is alive, as `LiveRunLink` says it."""

    def request(self, command: str, arguments: dict[str, Any], timeout: float) -> dict[str, Any]:
        raise NoRun("no subsystem is running")


@pytest.fixture
def project(tmp_path: Path) -> Path:
    """A subsystem file in a folder of its own, a file planted beside that folder (outside it), and
    two symbolic links in the folder that lead out: to the planted file, and to its folder."""
    folder = tmp_path / "project"
    folder.mkdir()
    fake_subsystem(folder)
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "secret.yaml").write_text(SECRET)
    (outside / "arm.xml").write_text(f"<mujoco>{SECRET}</mujoco>")
    (folder / "link.yaml").symlink_to(outside / "secret.yaml")
    (folder / "out").symlink_to(outside, target_is_directory=True)
    return folder


@pytest.fixture
def link(project: Path) -> FakeRunLink:
    return FakeRunLink(FakeJobHost(fake_subsystem(project), "pid"))


@pytest.fixture
def client(project: Path, link: FakeRunLink) -> TestClient:
    return TestClient(create_app(link, TOKEN, str(project / "switch_joint.yaml")), headers=BEARER)


def outside_files(project: Path) -> dict[str, tuple[str, int]]:
    """Every file of the folder beside the project: its content and modification time."""
    outside = project.parent / "outside"
    return {p.name: (p.read_text(), p.stat().st_mtime_ns) for p in sorted(outside.iterdir())}


def assert_refused(response, status: int, *words: str) -> None:
    assert response.status_code == status, response.text
    body = response.json()
    assert body["ok"] is False and "\n" not in body["error"] and all(w in body["error"] for w in words), body
    assert "the-content-no-answer-may-show" not in response.text


# --- one folder ---------------------------------------------------------------------------------

OUTSIDE_INCLUDES = ["../outside/secret.yaml", "{outside}/secret.yaml", "link.yaml", "out/secret.yaml",
                    "../../../../../../../../etc/passwd", "/etc/passwd"]


@pytest.mark.parametrize("include", OUTSIDE_INCLUDES)
def test_posted_yaml_that_includes_a_file_outside_the_folder_is_refused_with_403_and_the_file_is_never_read(
        client, project, include):
    before = outside_files(project)
    include = include.format(outside=project.parent / "outside")
    refused = client.post("/api/check", content=f"include: [{include}]\n", headers={"content-type": "application/yaml"})
    assert_refused(refused, 403, "E107", "is outside", str(project))
    assert "root:x:0" not in refused.text
    assert outside_files(project) == before


@pytest.mark.parametrize("include", ["../outside/secret.yaml", "/etc/passwd"])
def test_posted_yaml_with_no_subsystem_file_at_all_includes_nothing(project, include):
    alone = TestClient(create_app(NoRunLink(None), TOKEN), headers=BEARER)  # type: ignore[arg-type]
    refused = alone.post("/api/check", content=f"include: [{include}]\n", headers={"content-type": "text/plain"})
    assert_refused(refused, 403, "E107")


def test_posted_yaml_includes_what_is_in_the_folder_relative_to_the_subsystem_file(client):
    checked = client.post("/api/check", content="include: [switch_joint.yaml]\n", headers={"content-type": "text/plain"})
    assert checked.status_code == 200 and checked.json()["valid"] is True, checked.text


@pytest.mark.parametrize(("method", "route", "body"), [
    ("GET", "/api/check", None), ("GET", "/api/bus", None), ("GET", "/api/dictionary", None),
    ("GET", "/api/monitor/layout", None), ("POST", "/api/canvas/check", {"tasks": []}),
    ("POST", "/api/workspace/objects", {"name": "ready", "value": [0, 0, 0, 0, 0, 0]})])
def test_a_subsystem_file_that_includes_a_file_outside_its_folder_is_refused_by_every_route_that_checks_it(
        client, project, method, route, body):
    before = outside_files(project)
    file = project / "switch_joint.yaml"
    file.write_text(file.read_text() + "include: [out/secret.yaml]\n")
    assert_refused(client.request(method, route, json=body), 403, "E107")
    assert outside_files(project) == before


def test_the_canvas_of_a_file_that_includes_a_file_outside_its_folder_does_not_show_it(client, project):
    file = project / "switch_joint.yaml"
    file.write_text(file.read_text() + "include: [out/secret.yaml]\n")
    shown = client.get("/api/canvas")
    assert shown.status_code in (200, 403) and "the-content-no-answer-may-show" not in shown.text


def test_a_robot_file_outside_the_folder_is_refused_before_it_is_loaded(client, project):
    text = (project / "switch_joint.yaml").read_text()
    posted = text.replace("plant: {model: puma560,", "plant: {model: ../outside/arm.xml,", 1)
    assert posted != text, "the fake subsystem's plant line changed: update this test"
    assert_refused(client.post("/api/check", content=posted, headers={"content-type": "text/plain"}), 403, "E107", "robot file")


def test_pbo_check_on_the_command_line_keeps_reading_an_include_outside_the_folder(project):
    posted = project / "posted.yaml"
    posted.write_text("include: [../outside/secret.yaml]\n")
    assert not any(e.code == "E107" for e in check_file(posted).errors)
    assert [e.code for e in check_file(posted, root=project).errors if e.code == "E107"] == ["E107"]


@pytest.mark.parametrize("given", ["../outside/new.yaml", "{outside}/new.yaml", "out/new.yaml", "link.yaml",
                                   "/etc/pbo-saved.yaml", "bad\0name.yaml"])
def test_save_to_a_file_outside_the_folder_is_refused_with_403_and_never_reaches_the_run(client, project, link, given):
    before = outside_files(project)
    refused = client.post("/api/verbs/save", json={"file": given.format(outside=project.parent / "outside"), "force": True})
    assert_refused(refused, 403, "refused: ")
    assert [command for command, _ in link.requests if command == "save"] == []
    assert outside_files(project) == before and not Path("/etc/pbo-saved.yaml").exists()


def test_save_to_a_relative_path_writes_in_the_folder(client, project, link):
    client.post("/api/verbs/save", json={"file": "saved/live.yaml"})
    assert [arguments["file"] for command, arguments in link.requests if command == "save"] == [
        str(project.resolve() / "saved" / "live.yaml")]


def test_every_verb_argument_that_names_a_file_is_kept_in_the_folder():
    named = {(verb.name, argument.key) for verb in VERBS for argument in verb.arguments
             if argument.key in ("file", "path", "output") or "FILE" in (argument.metavar or "")}
    assert named == set(FILE_ARGUMENTS.items())


# --- no 500 ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("path", ["/static/%00", "/static/" + "a" * 5000, "/static/js/%00main.js",
                                  "/static/js/" + "a" * 300 + ".js"])
def test_a_static_path_the_file_system_cannot_take_is_404(client, path):
    assert_refused(client.get(path), 404, "no file /static/")


@pytest.mark.parametrize("route", ["/api/verbs/status", "/api/verbs/on", "/api/gaps",
                                   "/api/workspace/objects", "/api/canvas/check"])
def test_a_json_body_nested_too_deeply_is_400(client, route):
    refused = client.post(route, content="[" * 100_000, headers={"content-type": "application/json"})
    assert_refused(refused, 400, f"deeper than {guard.MAX_JSON_DEPTH}")
    nested = json.dumps({"row": [json.loads("[" * 40 + "]" * 40)]})
    assert_refused(client.post(route, content=nested, headers={"content-type": "application/json"}), 400, "deeper than")


@pytest.mark.parametrize("streamed", [False, True], ids=["with-length", "chunked"])
@pytest.mark.parametrize("route", ["/api/verbs/on", "/api/check", "/api/workspace/objects"])
def test_a_body_over_the_limit_is_413_whether_its_length_is_given_or_not(client, link, route, streamed):
    body = json.dumps({"task": "x" * (10 * 1024 * 1024)}).encode()
    content = iter([body[i:i + 65536] for i in range(0, len(body), 65536)]) if streamed else body
    assert_refused(client.post(route, content=content), 413, f"{guard.MAX_BODY_BYTES:,} bytes")
    assert link.requests == []


def test_a_bug_is_one_logged_line_with_a_reference_and_a_500_json_answer(client, monkeypatch, caplog):
    def broken() -> None:
        raise RuntimeError("a bug\nover two lines")

    monkeypatch.setattr(files, "lexicon", broken)
    with caplog.at_level(logging.ERROR, logger="pbo_runtime.api"):
        answered = client.get("/api/lexicon")
    assert answered.status_code == 500 and answered.json()["ok"] is False
    [record] = caplog.records
    reference = record.getMessage().split("internal error ", 1)[1].split()[0]
    assert reference in answered.json()["error"] and "\n" not in record.getMessage() and record.exc_info is None


# --- beyond loopback --------------------------------------------------------------------------------

@pytest.mark.parametrize(("host", "loopback"), [("127.0.0.1", True), ("127.1.2.3", True), ("::1", True), ("localhost", True),
                                                ("0.0.0.0", False), ("::", False), ("192.168.1.20", False), ("robot-pc", False)])
def test_only_addresses_of_this_machine_are_loopback(host, loopback):
    assert is_loopback(host) is loopback


def test_a_host_other_machines_reach_is_refused_with_the_risk_said_unless_allow_remote(project):
    said: list[str] = []
    warned: list[str] = []
    status = serve(str(project / "switch_joint.yaml"), "0.0.0.0", 0, None, None, said.append, warned.append)
    assert status == 1 and said == []
    [warning] = warned
    assert "--allow-remote" in warning and "clear text" in warning and "SSH tunnel" in warning


def test_the_folder_is_the_real_path_of_the_subsystem_files_folder(project):
    assert files.served_root(str(project / "switch_joint.yaml")) == os.path.realpath(project)
