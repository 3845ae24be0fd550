"""The API as one FastAPI app: every route behind the token, the HMI's page and files, the OpenAPI description.

`create_app(link, token, file)` assembles the routers (`api.verbs`, `api.files`, `api.streams`)
under one router whose single dependency is `auth.require_token`: no route is reachable without
the token, the OpenAPI description (`/openapi.json`) and the page included. Errors answer as the
routes do, `{"ok": false, "error": "one line"}`, and `api.guard` wraps it all: limits on bodies,
and one logged line for a bug. The description lists every refusal a route may answer with
(`replies.REFUSALS`) and not FastAPI's 422, which this app never answers (bad parameters are 400).
"""

from __future__ import annotations

import base64
import hashlib
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Depends, FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.utils import get_openapi
from fastapi.responses import FileResponse, HTMLResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from pbo_runtime.api import application, canvas, files, monitor, streams, verbs, workspace
from pbo_runtime.api.auth import COOKIE, require_token
from pbo_runtime.api.files import OutsideRoot
from pbo_runtime.api.guard import Guard
from pbo_runtime.api.link import RunLink
from pbo_runtime.api.replies import BAD_REQUEST, FORBIDDEN, REFUSALS, Reply, refusal
from pbo_runtime.objects.registry import installed_version

STATIC = Path(__file__).resolve().parent.parent / "hmi"  # the HMI: shipped in the package, no build step
MAX_STATIC_PATH = 200  # characters: the HMI's own paths are far shorter
MEDIA_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
               ".mjs": "text/javascript; charset=utf-8", ".css": "text/css; charset=utf-8",
               ".json": "application/json", ".svg": "image/svg+xml", ".png": "image/png"}


def page_policy(page: str) -> str:
    """The page's Content-Security-Policy: scripts only from this server (and the page's own import
    map, by its hash), nothing from the network, never framed by another site."""
    importmap = page.split('<script type="importmap">', 1)[1].split("</script>", 1)[0]
    digest = base64.b64encode(hashlib.sha256(importmap.encode()).digest()).decode()
    return (f"default-src 'self'; script-src 'self' 'sha256-{digest}'; style-src 'self' 'unsafe-inline'; "
            "img-src 'self' data:; connect-src 'self'; frame-ancestors 'none'; base-uri 'none'; form-action 'self'")


def static_file(path: str) -> Path:
    """The file under STATIC that `/static/PATH` names; 404 for anything else (a path out of it, one
    the file system cannot take: a NUL character, a name too long)."""
    missing = StarletteHTTPException(404, f"no file /static/{path[:MAX_STATIC_PATH]!r}")
    if len(path) > MAX_STATIC_PATH or "\0" in path:
        raise missing
    try:
        file = (STATIC / path).resolve()
        found = file.is_relative_to(STATIC) and file.is_file() and file.suffix in MEDIA_TYPES
    except (OSError, ValueError):
        found = False
    if not found:
        raise missing
    return file


def create_app(link: RunLink, token: str, file: str | None = None) -> FastAPI:
    """The API over `link`, answering only requests that show `token`; `file`: the subsystem file it was given."""
    app = FastAPI(title="pbo-runtime local API", version=installed_version(), openapi_url=None, docs_url=None,
                  redoc_url=None, description="The operator's verbs, the reports and live streams of a running subsystem. "
                                              "Every request needs the token pbo hmi printed.")
    app.state.link = link
    app.state.token = token
    app.state.file = file
    app.state.application_run = None  # the run of an application file the page started (api.application)
    app.state.application_subsystems = set()  # that file's subsystems, whose status streams the page may open

    protected = APIRouter(dependencies=[Depends(require_token)], responses=REFUSALS)

    index = (STATIC / "index.html").read_text(encoding="utf-8")
    policy = page_policy(index)

    @protected.get("/", response_class=HTMLResponse, include_in_schema=False)
    def page(request: Request) -> HTMLResponse:
        response = HTMLResponse(index, headers={"content-security-policy": policy, "cache-control": "no-cache"})
        if request.query_params.get("token"):  # the first load, from the printed URL: the browser keeps the token
            response.set_cookie(COOKIE, request.query_params["token"], httponly=True, samesite="strict", path="/")
        return response

    @protected.get("/static/{path:path}", include_in_schema=False)
    def static(path: str) -> FileResponse:
        file = static_file(path)
        return FileResponse(file, media_type=MEDIA_TYPES[file.suffix], headers={"cache-control": "no-cache"})

    @protected.get("/openapi.json", include_in_schema=False)
    def openapi() -> dict[str, Any]:
        return app.openapi()

    def description() -> dict[str, Any]:
        if app.openapi_schema is None:
            app.openapi_schema = without_validation_errors(get_openapi(
                title=app.title, version=app.version, description=app.description, routes=app.routes))
        return app.openapi_schema

    app.openapi = description  # type: ignore[method-assign]

    protected.include_router(verbs.router())
    protected.include_router(files.router())
    protected.include_router(streams.router())
    protected.include_router(canvas.router())
    protected.include_router(workspace.router())
    protected.include_router(monitor.router())
    protected.include_router(application.router())
    app.include_router(protected)

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> Reply:
        return Reply({"ok": False, "error": str(exc.detail)}, status_code=exc.status_code, headers=exc.headers)

    @app.exception_handler(OutsideRoot)
    async def outside_root(request: Request, exc: OutsideRoot) -> Reply:
        return refusal(FORBIDDEN, str(exc))

    @app.exception_handler(RequestValidationError)
    async def bad_parameters(request: Request, exc: RequestValidationError) -> Reply:
        problems = "; ".join(f"{'.'.join(map(str, e.get('loc', ())))}: {e.get('msg', '')}" for e in exc.errors())
        return refusal(BAD_REQUEST, f"bad parameters: {problems}", bad_request=True)

    app.add_middleware(Guard)
    return app


def without_validation_errors(description: dict[str, Any]) -> dict[str, Any]:
    """The OpenAPI description as the app behaves: the token every route needs (`auth`, shown as a bearer
    token), and without FastAPI's 422 answers and their schemas (a bad parameter is 400 here)."""
    for methods in description.get("paths", {}).values():
        for operation in methods.values():
            operation.get("responses", {}).pop("422", None)
    components = description.setdefault("components", {})
    schemas = components.get("schemas", {})
    for name in ("HTTPValidationError", "ValidationError"):
        schemas.pop(name, None)
    components["securitySchemes"] = {"token": {"type": "http", "scheme": "bearer",
                                               "description": "the token pbo hmi printed (or its cookie, or ?token=)"}}
    description["security"] = [{"token": []}]
    return description
