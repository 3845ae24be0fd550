"""The API fuzzed against its own OpenAPI description (schemathesis, in-process over ASGI, no sockets):
every route, with the token, answers no 5xx and nothing its description does not declare, and
without it nothing but 401.

The app is the one `pbo hmi FILE` serves, over a unit test's fake link (`tests.fake_job_host.FakeRunLink`:
verbs answered by the command table's dispatch on a fake job host) with a real table, on a copy of
a subsystem file in a folder of its own, which the fuzzing may rewrite. Bounded in examples, so the
whole run stays a few seconds.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator

import pytest
import schemathesis
from fastapi import FastAPI
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    ignored_auth,
    response_schema_conformance,
    status_code_conformance,
)

from pbo_runtime.api.app import create_app
from pbo_runtime.ipc import messages
from pbo_runtime.supervisor.commands import VERBS
from pbo_runtime.table.table import StateTable, TableLayout
from tests.fake_job_host import FakeJobHost, FakeRunLink, fake_subsystem
from tests.support import variables

TOKEN = "the-token-of-this-test"
BEARER = {"Authorization": f"Bearer {TOKEN}"}
VARS = variables(("q_m", "float64", (3,)), ("tau_u", "float64", (3,)), ("n", "int32", ()))
EXAMPLES = 8  # per route: enough to reach every refusal of a route, few enough for CI's budget
CHECKS = [not_a_server_error, status_code_conformance, content_type_conformance, response_schema_conformance, ignored_auth]


# The description as the app serves it, behind the token; it is the same whatever file and run the app has.
schema = schemathesis.openapi.from_asgi("/openapi.json", create_app(FakeRunLink(None), TOKEN), headers=BEARER)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def app(tmp_path_factory) -> Iterator[FastAPI]:
    """The app fuzzed: a subsystem file of its own, a fake link with a real table."""
    subsystem = fake_subsystem(tmp_path_factory.mktemp("fuzz"))
    table = StateTable.create(TableLayout.build(VARS, 2), messages.table_name(f"fuzz{uuid.uuid4().hex[:6]}",
                                                                               f"{os.getpid()}-{uuid.uuid4().hex[:6]}"))
    try:
        yield create_app(FakeRunLink(FakeJobHost(subsystem, "pid"), table.name), TOKEN, subsystem.file)
    finally:
        table.close()


def test_the_fuzzed_description_has_every_verb_and_every_route_of_the_files_canvas_workspace_and_monitor():
    paths = set(schema.raw_schema["paths"])
    assert {f"/api/verbs/{verb.name}" for verb in VERBS} <= paths
    assert {"/api/runs", "/api/lexicon", "/api/check", "/api/bus", "/api/graph", "/api/place", "/api/dictionary", "/api/gaps",
            "/api/canvas", "/api/canvas/check", "/api/canvas/job", "/api/workspace/applications", "/api/workspace/objects",
            "/api/workspace/run", "/api/monitor/layout", "/api/monitor/bus"} <= paths


@schema.parametrize()
@settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
          suppress_health_check=list(HealthCheck))
def test_every_route_answers_no_5xx_and_only_what_its_description_declares(case, app):
    case.call_and_validate(headers=BEARER, checks=CHECKS, app=app)
