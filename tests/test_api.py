"""The local API, in-process with FastAPI's TestClient (no sockets, no sleeps): the token on every
route, the Origin of WebSocket upgrades, a route per verb of the command table answering what the
supervisor's dispatch answers, the reports of a file, and the live streams of a real table.

The run behind the app is a fake link (`tests.fake_job_host.FakeRunLink`, over the fake job host of the command tests)
whose table is a real one made with StateTable.create; the last test drives a real `--clock sim` run.
"""

from __future__ import annotations

import json
import os
import uuid
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from fastapi.routing import APIWebSocketRoute
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from pbo_runtime.api import streams
from pbo_runtime.api.app import create_app
from pbo_runtime.api.auth import COOKIE
from pbo_runtime.api.jsonable import jsonable
from pbo_runtime.api.link import LiveRunLink, NoRun
from pbo_runtime.api.streams import MAX_VARIABLE_RATE
from pbo_runtime.api.verbs import LOCAL_VERBS
from pbo_runtime.errors import PboError
from pbo_runtime.ipc import messages
from pbo_runtime.ipc.control import answer
from pbo_runtime.supervisor.commands import VERBS, dispatch
from pbo_runtime.table.table import StateTable, TableLayout
from tests.fake_job_host import FakeJobHost, FakeRunLink, fake_subsystem
from tests.support import demo_copy, start_run, variables

TOKEN = "the-token-of-this-test"
BEARER = {"Authorization": f"Bearer {TOKEN}"}
VARS = variables(("q_m", "float64", (3,)), ("tau_u", "float64", (3,)), ("n", "int32", ()))


class NoRunLink(FakeRunLink):
    """A unit test's link when no run is alive: every request says so, as `LiveRunLink` does."""

    def request(self, command: str, arguments: dict[str, Any], timeout: float) -> dict[str, Any]:
        raise NoRun("no subsystem is running (no live state variable table of yours in /dev/shm): start one with `pbo run FILE`")


class SilentLink(FakeRunLink):
    """A unit test's link to a run whose supervisor does not answer."""

    def request(self, command: str, arguments: dict[str, Any], timeout: float) -> dict[str, Any]:
        raise PboError("the supervisor of 'fake' did not answer within 2 s")


@pytest.fixture(scope="module")
def subsystem(tmp_path_factory):
    return fake_subsystem(tmp_path_factory.mktemp("api"))


@pytest.fixture
def table() -> Iterator[StateTable]:
    """A real table named like a run of this (live) process; closed and unlinked after the test."""
    made = StateTable.create(TableLayout.build(VARS, 2), messages.table_name(f"api{uuid.uuid4().hex[:6]}",
                                                                              f"{os.getpid()}-{uuid.uuid4().hex[:6]}"))
    yield made
    made.close()


@pytest.fixture
def link(subsystem, table) -> FakeRunLink:
    return FakeRunLink(FakeJobHost(subsystem, "pid"), table.name)


@pytest.fixture
def client(link, subsystem) -> TestClient:
    return TestClient(create_app(link, TOKEN, subsystem.file))


def http_routes(client: TestClient) -> list[tuple[str, str]]:
    """Every HTTP route: those the OpenAPI description lists, and the two it leaves out (the page, itself)."""
    described = client.app.openapi()["paths"]
    return sorted([(method.upper(), path) for path, methods in described.items() for method in methods]
                  + [("GET", "/"), ("GET", "/openapi.json")])


def websocket_routes() -> list[str]:
    return sorted(route.path for route in streams.router().routes if isinstance(route, APIWebSocketRoute))


# --- the token and the Origin -----------------------------------------------------------------


@pytest.mark.parametrize("credentials", [
    {},
    {"headers": {"Authorization": "Bearer wrong"}},
    {"headers": {"Authorization": f"Basic {TOKEN}"}},
    {"cookies": {COOKIE: "wrong"}},
    {"params": {"token": "wrong"}},
], ids=["none", "wrong-bearer", "not-bearer", "wrong-cookie", "wrong-query"])
def test_every_route_refuses_a_request_without_the_right_token_with_401(subsystem, link, credentials):
    client = TestClient(create_app(link, TOKEN, subsystem.file), cookies=credentials.get("cookies"))
    routes = http_routes(client)
    assert ("GET", "/openapi.json") in routes and ("GET", "/") in routes and ("POST", "/api/verbs/stop") in routes
    for method, path in routes:
        response = client.request(method, path, headers=credentials.get("headers"), params=credentials.get("params"))
        assert response.status_code == 401, (method, path)
        assert response.json()["ok"] is False and response.json()["error"].startswith("unauthorized: ")
        assert response.headers["WWW-Authenticate"] == "Bearer"
    assert link.requests == []  # nothing reached the run


def test_the_first_page_load_with_the_token_sets_an_httponly_strict_cookie_that_lets_later_requests_in(client):
    page = client.get("/", params={"token": TOKEN})
    assert page.status_code == 200 and "pbo hmi" in page.text
    cookie = page.headers["set-cookie"]
    assert cookie.startswith(f"{COOKIE}={TOKEN};") and "HttpOnly" in cookie and "samesite=strict" in cookie.lower()
    assert client.post("/api/verbs/status").json()["ok"] is True  # the cookie alone, from now on


def test_the_page_allows_scripts_only_from_this_server_and_its_own_import_map(client):
    page = client.get("/", headers=BEARER)
    policy = page.headers["content-security-policy"]
    assert "script-src 'self' 'sha256-" in policy and "frame-ancestors 'none'" in policy and "unsafe-eval" not in policy
    assert '<script type="module" src="/static/js/main.js">' in page.text


@pytest.mark.parametrize(("path", "media_type"), [("js/main.js", "text/javascript"), ("css/hmi.css", "text/css"),
                                                  ("vendor/preact/preact.mjs", "text/javascript")])
def test_the_hmis_files_are_served_behind_the_token_with_their_media_type(client, path, media_type):
    assert client.get(f"/static/{path}").status_code == 401
    served = client.get(f"/static/{path}", headers=BEARER)
    assert served.status_code == 200 and served.headers["content-type"].startswith(media_type)


@pytest.mark.parametrize("path", ["../api/app.py", "..%2Fapi%2Fapp.py", "vendor/../../api/auth.py",
                                  "vendor/vendored.json.missing",
                                  "js", "../../../../../etc/passwd"])
def test_no_file_outside_the_hmis_own_is_served(client, path):
    refused = client.get(f"/static/{path}", headers=BEARER)
    assert refused.status_code == 404 and refused.json()["ok"] is False


def test_the_openapi_description_lists_every_route_behind_the_token(client):
    assert client.get("/openapi.json").status_code == 401
    paths = client.get("/openapi.json", headers=BEARER).json()["paths"]
    assert {f"/api/verbs/{verb.name}" for verb in VERBS} <= set(paths)
    assert {"/api/lexicon", "/api/check", "/api/bus", "/api/graph", "/api/runs"} <= set(paths)
    assert paths["/api/verbs/on"]["post"]["requestBody"]["content"]["application/json"]["schema"]["properties"] == {
        "task": {"description": "the task's name"}}


@pytest.mark.parametrize("path", ["/api/streams/status", "/api/streams/variables"])
def test_a_websocket_upgrade_from_a_foreign_origin_is_refused_even_with_the_token(client, path):
    with (pytest.raises(WebSocketDisconnect) as refused,
          client.websocket_connect(path, headers={**BEARER, "Origin": "http://evil.example"})):
        pass
    assert refused.value.code == 1008 and "origin 'http://evil.example' is not this server's" in refused.value.reason


@pytest.mark.parametrize("path", ["/api/streams/status", "/api/streams/variables"])
def test_a_websocket_upgrade_without_the_token_is_refused(client, path):
    with pytest.raises(WebSocketDisconnect) as refused, client.websocket_connect(path, headers={"Origin": "http://testserver"}):
        pass
    assert (refused.value.code, refused.value.reason) == (1008, "unauthorized: no token")


def test_a_websocket_upgrade_from_the_servers_own_page_with_its_cookie_is_served(client):
    client.get("/", params={"token": TOKEN})
    with client.websocket_connect("/api/streams/status", headers={"Origin": "http://testserver"}) as stream:
        assert stream.receive_json()["configuration"] == "pid"


# --- the verbs --------------------------------------------------------------------------------


def test_every_verb_of_the_command_table_is_a_route_and_no_route_is_a_verb_the_table_lacks(client):
    verb_routes = {path for method, path in http_routes(client) if path.startswith("/api/verbs/")}
    assert verb_routes == {f"/api/verbs/{verb.name}" for verb in VERBS}
    assert all(method == "POST" for method, path in http_routes(client) if path.startswith("/api/verbs/"))
    assert {verb.name for verb in VERBS if verb.handler is None} == set(LOCAL_VERBS)


def served(subsystem, command: str, arguments: dict[str, Any]) -> dict[str, Any]:
    """What the supervisor answers on a fresh fake host, as the control queue would carry it."""
    return jsonable(answer(lambda c, a: dispatch(FakeJobHost(subsystem, "pid"), c, a), command, arguments))


@pytest.mark.parametrize(("verb", "body", "status"), [
    ("status", {}, 200),
    ("off", {"task": "pid"}, 200),
    ("on", {"task": "pd"}, 409),  # not in the running configuration: the run's state refuses
    ("on", {"task": "nope"}, 400),  # no such task: the request is wrong
    ("clear", {"task": "pid"}, 409),
    ("switch", {"configuration": "pd"}, 200),
    ("switch", {"configuration": 3}, 400),
    ("job", {"job": "hold"}, 200),
    ("job", {"job": "move", "object": [1, "x"]}, 400),
    ("event", {"task": "pid", "values": [1.0]}, 400),
    ("set", {"task": "pid", "param": "kp", "values": ["1.0e+308"]}, 400),  # out of its range: the checker's E308, as pbo set
    ("set", {"task": "pid", "param": "kp", "values": [".nan"]}, 400),
    ("status", {"verbose": True}, 400),  # an argument the verb does not take
    ("stop", {}, 200),
])
def test_a_verbs_route_answers_what_the_supervisors_dispatch_answers(subsystem, verb, body, status):
    expected = served(subsystem, verb, body)
    host = FakeJobHost(subsystem, "pid")
    response = TestClient(create_app(FakeRunLink(host), TOKEN)).post(f"/api/verbs/{verb}", json=body, headers=BEARER)
    assert response.status_code == status
    reply = response.json()
    if verb == "switch" and status == 200:  # the only figure that depends on how long the host took
        reply.pop("took"), expected.pop("took")
        reply["message"] = expected["message"] = reply["message"].split(" in ")[0]
    assert reply == expected
    assert reply["ok"] is (status == 200) and reply.get("bad_request", False) is (status == 400)


@pytest.mark.parametrize(("verb", "body"), [("job", '{"job": "reach", "object": [0, 0, NaN, 0, 0, 0]}'),
                                            ("event", '{"task": "pid", "values": [Infinity]}')])
def test_a_number_that_is_not_finite_in_a_bodys_json_is_refused_as_the_command_line_refuses_it(subsystem, verb, body):
    host = FakeJobHost(subsystem, "pid")
    response = TestClient(create_app(FakeRunLink(host), TOKEN)).post(f"/api/verbs/{verb}", content=body, headers=BEARER)
    assert response.status_code == 400 and "finite" in response.json()["error"], response.json()


@pytest.mark.parametrize("verb", [verb for verb in VERBS if verb.handler is not None], ids=lambda verb: verb.name)
def test_every_served_verb_answers_a_bare_request_as_dispatch_does(subsystem, verb):
    # a verb the table gains later is covered here with no change: whatever it answers to an empty request
    expected = served(subsystem, verb.name, {})
    response = TestClient(create_app(FakeRunLink(FakeJobHost(subsystem, "pid")), TOKEN)).post(
        f"/api/verbs/{verb.name}", headers=BEARER)
    reply = response.json()
    for volatile in ("took", "message"):
        if expected.get("ok"):
            reply.pop(volatile, None), expected.pop(volatile, None)
    assert reply == expected
    assert response.status_code == (200 if expected["ok"] else 400 if expected.get("bad_request") else 409)


@pytest.mark.parametrize(("body", "refusal"), [
    ("[1, 2]", "the body must be a JSON object of the verb's arguments, got: list"),
    ("{task: pid}", "the body is not JSON: "),
])
def test_a_body_that_is_not_a_json_object_is_a_bad_request_that_never_reaches_the_run(client, link, body, refusal):
    response = client.post("/api/verbs/off", content=body, headers=BEARER)
    assert response.status_code == 400 and response.json()["error"].startswith(refusal)
    assert link.requests == []


def test_without_a_run_a_verb_answers_404_with_the_operator_verbs_hint(subsystem):
    response = TestClient(create_app(NoRunLink(FakeJobHost(subsystem, "pid")), TOKEN)).post("/api/verbs/status", headers=BEARER)
    assert response.status_code == 404
    assert response.json() == {"ok": False, "error": "no subsystem is running (no live state variable table of yours in "
                                                     "/dev/shm): start one with `pbo run FILE`"}


def test_a_supervisor_that_does_not_answer_is_503(subsystem):
    response = TestClient(create_app(SilentLink(FakeJobHost(subsystem, "pid")), TOKEN)).post("/api/verbs/on", json={"task": "pd"},
                                                                                               headers=BEARER)
    assert (response.status_code, response.json()["error"]) == (503, "the supervisor of 'fake' did not answer within 2 s")


def test_svar_reads_the_rows_pbo_svar_prints_from_the_table(client, table):
    table.write("q_m", [0.5, -0.25, 1.0], when=1.0)
    reply = client.post("/api/verbs/svar", json={"names": ["q_m", "n"]}, headers=BEARER).json()
    assert reply["ok"] is True and [row["name"] for row in reply["variables"]] == ["q_m", "n"]
    q_m = reply["variables"][0]
    assert (q_m["value"], q_m["sequence"], q_m["writer"]) == ("[+0.5000, -0.2500, +1.0000]", 1, "job control")
    unknown = client.post("/api/verbs/svar", json={"names": ["q_mes"]}, headers=BEARER)
    assert unknown.status_code == 400 and unknown.json()["error"] == "no variable 'q_mes' in 'fake' (variables: q_m, tau_u, n)"


# --- what needs only the file -------------------------------------------------------------------


def test_lexicon_check_bus_and_graph_of_the_file_pbo_hmi_was_given(client, subsystem):
    modules = client.get("/api/lexicon", headers=BEARER).json()["modules"]
    assert "pid_joint" in [m["name"] for m in modules]
    check = client.get("/api/check", headers=BEARER).json()
    assert (check["valid"], check["errors"], check["subsystem"], check["file"]) == (True, [], "puma_switch", subsystem.file)
    assert set(client.get("/api/bus", headers=BEARER).json()["configurations"]) == {"pid", "pd"}
    graph = client.get("/api/graph", params={"config": "pd"}, headers=BEARER)
    assert graph.headers["content-type"] == "image/svg+xml" and b"<svg" in graph.content
    wrong = client.get("/api/bus", params={"config": "nope"}, headers=BEARER)
    assert wrong.status_code == 400
    assert wrong.json()["error"] == f"no configuration 'nope' in {subsystem.file} (configurations: pid, pd)"


def test_placement_queries_say_which_modules_the_canvas_may_place_and_why_not_the_rest(client):
    reply = client.get("/api/place", params={"config": "pid", "module": ["pid_joint", "gravity_compensation"]},
                       headers=BEARER).json()
    verdicts = {m["module"]: m for m in reply["modules"]}
    assert reply["ok"] is True and verdicts["pid_joint"]["legal"] is False and verdicts["pid_joint"]["code"] == "E407"
    assert verdicts["gravity_compensation"]["legal"] is True
    wrong = client.get("/api/place", params={"config": "nope"}, headers=BEARER)
    assert wrong.status_code == 400 and wrong.json()["error"].startswith("no configuration 'nope'")


def test_the_job_dictionary_and_the_gaps_of_a_row_of_icons_are_routes(client):
    dictionary = client.get("/api/dictionary", headers=BEARER).json()
    assert dictionary["ok"] is True and {"reach", "settle", "hold"} <= set(dictionary["jobs"])
    assert "tour" in dictionary["applications"]
    gaps = client.post("/api/gaps", json={"row": ["settle", "reach"]}, headers=BEARER).json()
    assert gaps["ok"] is True and gaps["complete"] is False
    assert [(gap["step"], gap["object_type"]) for gap in gaps["gaps"]] == [(1, "joint_position"), (2, "joint_position")]
    assert client.post("/api/gaps", json={"rows": []}, headers=BEARER).status_code == 400  # a body without its row


def test_posted_yaml_is_checked_with_messages_located_in_it(client):
    reply = client.post("/api/check", content="subsystem: x\nrtpus: [r]\nvariables: {}\ntasks: {}\nconfigurations: {}\nfoo: 1\n",
                        headers={**BEARER, "Content-Type": "application/yaml"}).json()
    assert reply["ok"] is True and reply["valid"] is False
    unknown = next(e for e in reply["errors"] if "foo" in e["message"])
    assert (unknown["file"], unknown["line"], unknown["column"]) == ("posted.yaml", 6, 1)
    assert "posted.yaml:6:1: error" in reply["text"] and "pbo-check-" not in reply["text"]


def test_without_a_file_or_a_run_the_file_routes_say_how_to_give_one(subsystem):
    client = TestClient(create_app(NoRunLink(FakeJobHost(subsystem, "pid")), TOKEN))
    for path in ("/api/check", "/api/bus", "/api/graph"):
        response = client.get(path, headers=BEARER)
        assert response.status_code == 404 and response.json()["error"].startswith("no subsystem file: ")
        assert response.json()["error"].endswith("start it as pbo hmi FILE")
    assert client.get("/api/lexicon", headers=BEARER).status_code == 200  # needs no file


# --- the streams ------------------------------------------------------------------------------


def test_the_variable_stream_sends_the_requested_variables_from_the_table(client, table):
    table.write("q_m", [1.0, 2.0, 3.0], when=1.0)
    table.write("n", 7, when=1.0)
    with client.websocket_connect("/api/streams/variables?names=q_m,n&rate=100", headers=BEARER) as stream:
        head = stream.receive_json()
        assert (head["ok"], head["names"], head["rate"]) == (True, ["q_m", "n"], 100.0)
        first = stream.receive_json()
        assert first["values"] == {"q_m": [1.0, 2.0, 3.0], "n": 7} and first["sequences"] == {"q_m": 1, "n": 1}
        table.write("q_m", np.array([4.0, 5.0, 6.0]), when=2.0)
        while (message := stream.receive_json())["sequences"]["q_m"] == 1:
            pass  # messages come at the requested rate; the write shows in a later one
        assert message["values"]["q_m"] == [4.0, 5.0, 6.0]


@pytest.mark.parametrize(("query", "refusal"), [
    (f"names=q_m&rate={MAX_VARIABLE_RATE + 1:g}", "rate must be > 0 and at most 100 Hz, got: 101 Hz; ask for 100 or less"),
    ("names=q_m&rate=1000", "rate must be > 0 and at most 100 Hz, got: 1000 Hz; ask for 100 or less"),
    ("names=q_m&rate=0", "rate must be > 0 and at most 100 Hz, got: 0 Hz; ask for 100 or less"),
    ("names=q_m&rate=fast", "rate must be a number of Hz, got: 'fast'"),
    ("names=q_m,q_mes", "no variable 'q_mes' in 'fake' (variables: q_m, tau_u, n)"),
])
def test_the_variable_stream_refuses_what_it_cannot_serve_with_a_message(client, query, refusal):
    with client.websocket_connect(f"/api/streams/variables?{query}", headers=BEARER) as stream:
        assert stream.receive_json() == {"ok": False, "error": refusal}
        with pytest.raises(WebSocketDisconnect) as closed:
            stream.receive_json()
    assert closed.value.code == 1008


def test_the_status_stream_sends_the_status_reply_and_refuses_more_than_its_rate(client, link):
    with client.websocket_connect("/api/streams/status?rate=10", headers=BEARER) as stream:
        first, second = stream.receive_json(), stream.receive_json()
    assert first["ok"] and first["configuration"] == "pid" and second["ok"]
    assert link.requests[:2] == [("status", {}), ("status", {})]
    with client.websocket_connect("/api/streams/status?rate=50", headers=BEARER) as stream:
        assert stream.receive_json()["error"] == "rate must be > 0 and at most 10 Hz, got: 50 Hz; ask for 10 or less"


def test_a_stream_without_a_run_says_so_and_closes(subsystem):
    client = TestClient(create_app(NoRunLink(FakeJobHost(subsystem, "pid")), TOKEN))
    with client.websocket_connect("/api/streams/variables", headers=BEARER) as stream:
        assert stream.receive_json() == {"ok": False, "error": "no subsystem is running"}


def test_every_websocket_route_is_behind_the_token(client):
    sockets = websocket_routes()
    assert sockets == ["/api/streams/status", "/api/streams/variables"]
    for path in sockets:
        with pytest.raises(WebSocketDisconnect), client.websocket_connect(path, headers={"Authorization": "Bearer wrong"}):
            pass


# --- a real run ---------------------------------------------------------------------------------


@pytest.mark.multiprocess
def test_the_api_drives_a_real_simulated_run_and_streams_its_variables(tmp_path):
    file = demo_copy(tmp_path, "api_e2e")
    report = tmp_path / "report.json"
    run = start_run(file, tmp_path, "--clock", "sim", "--duration", "0", "--report", str(report))
    try:
        client = TestClient(create_app(LiveRunLink("api_e2e"), TOKEN, None))
        status = client.post("/api/verbs/status", headers=BEARER).json()
        assert (status["ok"], status["subsystem"], status["file"]) == (True, "api_e2e", str(file))
        assert client.get("/api/check", headers=BEARER).json()["subsystem"] == "api_e2e"  # the run's own file
        off = client.post("/api/verbs/off", json={"task": "logger"}, headers=BEARER)
        assert off.json() == {"ok": True, "task": "logger", "state": "OFF", "message": "task 'logger' is OFF"}
        refused = client.post("/api/verbs/off", json={"task": "logger"}, headers=BEARER)
        assert refused.status_code == 409 and refused.json()["error"] == "task 'logger' is OFF: only an ON task can be turned off"
        with client.websocket_connect("/api/streams/variables?names=q_m,tau_u,q_d&rate=100", headers=BEARER) as stream:
            assert stream.receive_json()["names"] == ["q_m", "tau_u", "q_d"]
            values = stream.receive_json()["values"]
        assert values["q_d"] == [0.3, -0.5, 0.5, 0.2, 0.4, 0.2] and len(values["q_m"]) == 6
        assert client.post("/api/verbs/stop", headers=BEARER).json()["ok"] is True
        run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    assert json.loads(report.read_text())["stopped_by"] == "pbo stop"
    response = client.post("/api/verbs/status", headers=BEARER)
    assert response.status_code == 404 and "subsystem 'api_e2e' is not running" in response.json()["error"]


# --- pbo hmi ----------------------------------------------------------------------------------


def test_pbo_hmi_prints_the_loopback_url_with_its_token_even_when_listening_on_every_interface():
    from pbo_runtime.api.server import url

    assert url("127.0.0.1", 8470, "abc") == "http://127.0.0.1:8470/?token=abc"
    assert url("0.0.0.0", 8470, "abc") == "http://127.0.0.1:8470/?token=abc"
    assert url("::1", 8470, "abc") == "http://[::1]:8470/?token=abc"


def test_pbo_hmi_refuses_a_port_in_use_with_what_to_do():
    from pbo_runtime.api.server import bind

    first = bind("127.0.0.1", 0)
    try:
        port = first.getsockname()[1]
        with pytest.raises(PboError, match=rf"^port {port} on 127.0.0.1 is in use \(another pbo hmi\?\): pass --port N, "
                                           r"or --port 0 for any free one$"):
            bind("127.0.0.1", port)
    finally:
        first.close()


def test_pbo_hmi_serves_the_run_of_the_files_subsystem(tmp_path, subsystem):
    from pbo_runtime.api.server import describe_run, subsystem_of

    assert subsystem_of(subsystem.file) == "puma_switch"
    (tmp_path / "broken.yaml").write_text("subsystem: [")
    assert subsystem_of(str(tmp_path / "broken.yaml")) is None
    said = describe_run(LiveRunLink("no_such_subsystem_here"))
    assert said.startswith("no run of 'no_such_subsystem_here' yet: lexicon, check, bus and graph are served")
    with pytest.raises(NoRun, match=r"^no live run has run id"):
        describe_run(LiveRunLink(None, "0-no-such-run"))


@pytest.mark.parametrize("run, starts", [(None, True), ("0-", False)])
def test_pbo_hmi_starts_beside_several_runs_until_a_run_id_is_what_cannot_be_told_apart(monkeypatch, run, starts):
    """Several live runs and none named: the server starts (a request says which are alive); a run id's
    prefix that matches several is the operator's to lengthen."""
    from pbo_runtime.api import link
    from pbo_runtime.api.server import describe_run
    from pbo_runtime.ipc.runs import SeveralRuns

    def fake_two_runs_alive(subsystem: str | None, run: str | None) -> tuple[str, str, str]:
        raise SeveralRuns("2 runs are alive: a; b; pass --subsystem NAME or --run ID")

    monkeypatch.setattr(link, "find_live_run", fake_two_runs_alive)
    if starts:
        assert describe_run(LiveRunLink(None, run)).startswith("2 runs are alive: a; b; pass --subsystem NAME or --run ID; "
                                                               "until one is the only one")
    else:
        with pytest.raises(NoRun, match=r"^2 runs are alive") as refused:
            describe_run(LiveRunLink(None, run))
        assert refused.value.several
