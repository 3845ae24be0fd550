"""The API as one FastAPI app: every route behind the token, the page, the OpenAPI description.

`create_app(link, token, file)` assembles the routers (`api.verbs`, `api.files`, `api.streams`)
under one router whose single dependency is `auth.require_token`: no route is reachable without
the token, the OpenAPI description (`/openapi.json`) and the page included. Errors answer as the
routes do, `{"ok": false, "error": "one line"}`.
"""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from pbo_runtime.api import files, streams, verbs
from pbo_runtime.api.auth import COOKIE, require_token
from pbo_runtime.api.link import RunLink
from pbo_runtime.api.replies import BAD_REQUEST, Reply, refusal
from pbo_runtime.objects.registry import installed_version

# The HMI's page comes with the next issue; until then `/` says what is served.
PLACEHOLDER = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>pbo hmi</title></head>
<body>
<h1>pbo hmi</h1>
<p>The local API of pbo-runtime is running. The browser HMI is not part of this version yet.</p>
<ul>
<li><a href="/openapi.json">/openapi.json</a>: every route, described</li>
<li><a href="/api/runs">/api/runs</a>: your live runs</li>
<li><a href="/api/lexicon">/api/lexicon</a>: the module library</li>
<li><a href="/api/check">/api/check</a>: the checker's verdict on the file</li>
<li><a href="/api/graph">/api/graph</a>: the configuration's block diagram</li>
</ul>
</body></html>
"""


def create_app(link: RunLink, token: str, file: str | None = None) -> FastAPI:
    """The API over `link`, answering only requests that show `token`; `file`: the subsystem file it was given."""
    app = FastAPI(title="pbo-runtime local API", version=installed_version(), openapi_url=None, docs_url=None,
                  redoc_url=None, description="The operator's verbs, the reports and live streams of a running subsystem. "
                                              "Every request needs the token pbo hmi printed.")
    app.state.link = link
    app.state.token = token
    app.state.file = file

    protected = APIRouter(dependencies=[Depends(require_token)])

    @protected.get("/", response_class=HTMLResponse, include_in_schema=False)
    def page(request: Request) -> HTMLResponse:
        response = HTMLResponse(PLACEHOLDER)
        if request.query_params.get("token"):  # the first load, from the printed URL: the browser keeps the token
            response.set_cookie(COOKIE, request.query_params["token"], httponly=True, samesite="strict", path="/")
        return response

    @protected.get("/openapi.json", include_in_schema=False)
    def openapi() -> dict[str, Any]:
        return app.openapi()

    protected.include_router(verbs.router())
    protected.include_router(files.router())
    protected.include_router(streams.router())
    app.include_router(protected)

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> Reply:
        return Reply({"ok": False, "error": str(exc.detail)}, status_code=exc.status_code, headers=exc.headers)

    @app.exception_handler(RequestValidationError)
    async def bad_parameters(request: Request, exc: RequestValidationError) -> Reply:
        problems = "; ".join(f"{'.'.join(map(str, e.get('loc', ())))}: {e.get('msg', '')}" for e in exc.errors())
        return refusal(BAD_REQUEST, f"bad parameters: {problems}", bad_request=True)

    return app
