"""What needs only a subsystem file, not a run: the lexicon, the checker, the bus report, the diagram.

    GET  /api/lexicon               every module's ports and parameters (pbo lexicon --format json)
    GET  /api/check                 the checker's verdict on the file (pbo check)
    POST /api/check                 the same on YAML text sent as the body (the editor's unsaved file)
    GET  /api/bus?config=NAME       predicted bus utilisation (pbo bus --format json)
    GET  /api/graph?config=NAME     the configuration's block diagram as SVG (pbo graph -o x.svg)
    GET  /api/place?config=NAME     which lexicon modules can be placed in a configuration, and why
         [&tasks=a,b][&rtpu=R]      not the rest (pbo place --format json): the canvas dims those
         [&module=M...]
    GET  /api/dictionary            the job dictionary: object types, jobs, applications, objects,
                                    each with its class and edges (pbo check --format json's part)
    POST /api/gaps                  {"row": [icon, ...]}: where a partial application's gaps are,
                                    and of which object type (the workspace's row, left to right)

The file is the one `pbo hmi FILE` was given, or else the attached run's own (its status reply
names it); with neither, these answer 404 and say so. The lexicon needs no file. Its folder is the
one tree the API reads and writes (`served_root`): every load here is confined to it
(`config.root`), so an `include:` that leaves it, in the file or in YAML posted to be checked, is
an error (E107) and is never read. Posted YAML is checked as if it were a file named posted.yaml
in that folder; with no file at all, in an empty one.
"""

from __future__ import annotations

import os
import tempfile
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request
from fastapi.responses import Response
from pydantic import BaseModel
from starlette.concurrency import run_in_threadpool

from pbo_runtime.analysis import bus
from pbo_runtime.analysis.placement import placement_report
from pbo_runtime.api.guard import MAX_BODY_BYTES
from pbo_runtime.api.link import RunLink
from pbo_runtime.api.replies import BAD_REQUEST, NO_RUN, TOO_LARGE, Reply, refusal
from pbo_runtime.config import bus_model
from pbo_runtime.config.loader import CheckResult, check_file, format_diagnostics
from pbo_runtime.config.root import OUTSIDE_ROOT, confined, is_within
from pbo_runtime.edit.job_dictionary import job_dictionary, row_gaps
from pbo_runtime.errors import ConfigError, PboError
from pbo_runtime.reports.graph import draw
from pbo_runtime.reports.lexicon import lexicon

MAX_POSTED_YAML = MAX_BODY_BYTES  # a subsystem file, not a data set
POSTED_NAME = "posted.yaml"  # how messages name YAML sent as a body


class NoFile(PboError):
    """Neither `pbo hmi FILE` nor a live run says which subsystem file to read."""


def subsystem_file(request: Request) -> str:
    """The file given to `pbo hmi`, or the attached run's; NoFile when there is neither."""
    given: str | None = request.app.state.file
    if given:
        return given
    link: RunLink = request.app.state.link
    try:
        reply = link.request("status", {}, 1.0)
    except PboError as exc:
        raise NoFile(f"no subsystem file: pbo hmi was given none and no run names one ({exc}); "
                     f"start it as pbo hmi FILE") from None
    if not reply.get("ok") or not reply.get("file"):
        raise NoFile("no subsystem file: pbo hmi was given none and the run did not say its own; start it as pbo hmi FILE")
    return str(reply["file"])


class OutsideRoot(PboError):
    """A path from a request, or an include, that leaves the served tree (`..`, absolute, a symlink
    out of it): 403 from any route (`api.app`)."""


def served_root(file: str) -> str:
    """The one tree the API reads and writes: the real path of the subsystem file's folder."""
    return os.path.realpath(os.path.dirname(os.path.abspath(file)))


def in_tree(file: str) -> AbstractContextManager[None]:
    """Loads and checks confined to `file`'s folder (`config.root`): no file outside it is read."""
    return confined(served_root(file))


def within(root: str, given: str) -> str:
    """`given` (relative to `root`, or absolute) as the real path it names, if that is inside `root`; else OutsideRoot."""
    if "\0" in given:
        raise OutsideRoot(f"refused: the path {given[:200]!r} holds a NUL character")
    path = os.path.join(root, given)  # an absolute path stands alone
    if not is_within(path, root):
        raise OutsideRoot(f"refused: {given[:200]!r} is outside {root}, the only folder this server reads and writes")
    return os.path.realpath(path)


def diagnostic(d: ConfigError, rename: tuple[str, str] | None = None) -> dict[str, Any]:
    file = d.file.replace(*rename) if rename else d.file
    return {"file": file, "line": d.line, "column": d.column, "severity": d.severity, "code": d.code,
            "message": d.message, "hint": d.hint,
            "notes": [{"file": n.file.replace(*rename) if rename else n.file, "line": n.line, "column": n.column,
                       "message": n.message} for n in d.notes]}


def check_reply(result: CheckResult, rename: tuple[str, str] | None = None) -> dict[str, Any]:
    """The checker's verdict: ok, every error and warning located, and the text pbo check prints."""
    text = format_diagnostics(result)
    if rename:
        text = text.replace(*rename)
    reply: dict[str, Any] = {"ok": True, "valid": not result.errors, "errors": [diagnostic(e, rename) for e in result.errors],
                             "warnings": [diagnostic(w, rename) for w in result.warnings], "text": text}
    if result.subsystem is not None and not result.errors:
        sub = result.subsystem
        reply.update(subsystem=sub.name, configurations={name: list(c.tasks) for name, c in sub.configurations.items()},
                     init_order=list(sub.init_order))
    return reply


def check_text(text: str, root: str | None) -> dict[str, Any]:
    """Check YAML text as if it were a file named posted.yaml in `root` (its includes confined to
    it), or, with no root, in an empty folder of its own; OutsideRoot when it includes a file outside."""
    if root is None:
        with tempfile.TemporaryDirectory(prefix="pbo-check-") as folder:
            return check_text(text, os.path.realpath(folder))
    path = str(Path(root) / POSTED_NAME)
    result = check_file(path, root=root, text=text)
    try:
        refuse_outside(result)
    except OutsideRoot as exc:
        raise OutsideRoot(str(exc).replace(path, POSTED_NAME)) from None
    return check_reply(result, (path, POSTED_NAME))


def refuse_outside(result: CheckResult) -> None:
    """OutsideRoot (403) naming the first file the check refused to read for leaving the served folder, if any."""
    outside = [e for e in result.errors if e.code == OUTSIDE_ROOT]
    if outside:
        raise OutsideRoot(f"refused: {outside[0].format().splitlines()[0]}")


def loaded(file: str, what: str) -> Any:
    """The checked subsystem of `file`, read within its folder; ValueError naming the first error when
    it has any, OutsideRoot when that is a file outside the folder."""
    result = check_file(file, root=served_root(file))
    refuse_outside(result)
    if result.errors or result.subsystem is None:
        first = result.errors[0].format().splitlines()[0] if result.errors else f"{file}: not a subsystem file"
        raise ValueError(f"cannot {what}: {file} has {len(result.errors)} error(s), the first: {first}; "
                         f"GET /api/check lists them all")
    return result.subsystem


def bus_reply(file: str, configuration: str | None) -> dict[str, Any]:
    subsystem = loaded(file, "report the bus")
    if configuration is not None and configuration not in subsystem.configurations:
        raise ValueError(f"no configuration '{configuration}' in {file} (configurations: {', '.join(subsystem.configurations)})")
    names = [configuration] if configuration else list(subsystem.configurations)
    return {"ok": True, "file": file, "configurations": {name: bus.as_json(bus_model.predict(subsystem, name)) for name in names}}


def graph_svg(file: str, configuration: str | None) -> bytes:
    subsystem = loaded(file, "draw the diagram")
    with tempfile.TemporaryDirectory(prefix="pbo-graph-") as folder:
        path = draw(subsystem, configuration, os.path.join(folder, "graph.svg"))  # ValueError: no such configuration
        return path.read_bytes()


def router() -> APIRouter:
    routes = APIRouter(prefix="/api", tags=["files"])

    @routes.get("/lexicon", summary="the module library: every module's ports and parameters (pbo lexicon)")
    def get_lexicon() -> Reply:
        return Reply({"ok": True, "modules": lexicon()})

    @routes.get("/check", summary="check the subsystem file like a compiler (pbo check)")
    def get_check(request: Request) -> Reply:
        try:
            file = subsystem_file(request)
        except NoFile as exc:
            return refusal(NO_RUN, str(exc))
        result = check_file(file, root=served_root(file))
        refuse_outside(result)  # 403 (api.app)
        return Reply({**check_reply(result), "file": file})

    @routes.post("/check", summary="check YAML text sent as the body (text/plain or application/yaml)",
                 openapi_extra={"requestBody": {"required": True, "content": {"application/yaml": {"schema": {"type": "string"}},
                                                                              "text/plain": {"schema": {"type": "string"}}}}})
    async def post_check(request: Request) -> Reply:
        raw = await request.body()
        if len(raw) > MAX_POSTED_YAML:
            return refusal(TOO_LARGE, f"the YAML is {len(raw)} bytes, more than {MAX_POSTED_YAML} taken")
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            return refusal(BAD_REQUEST, f"the YAML is not UTF-8 text: {exc}", bad_request=True)
        try:
            root: str | None = served_root(await run_in_threadpool(subsystem_file, request))
        except NoFile:
            root = None
        return Reply(await run_in_threadpool(check_text, text, root))

    @routes.get("/bus", summary="predicted bus utilisation per configuration (pbo bus --format json)")
    def get_bus(request: Request, config: str | None = None) -> Reply:
        try:
            return Reply(bus_reply(subsystem_file(request), config))
        except NoFile as exc:
            return refusal(NO_RUN, str(exc))
        except ValueError as exc:
            return refusal(BAD_REQUEST, str(exc), bad_request=True)

    @routes.get("/graph", summary="a configuration's block diagram as SVG (pbo graph -o out.svg)", response_class=Response,
                responses={200: {"description": "the diagram", "content": {"image/svg+xml": {"schema": {"type": "string"}}}}})
    def get_graph(request: Request, config: str | None = None) -> Response:
        try:
            return Response(graph_svg(subsystem_file(request), config), media_type="image/svg+xml")
        except NoFile as exc:
            return refusal(NO_RUN, str(exc))
        except ValueError as exc:
            return refusal(BAD_REQUEST, str(exc), bad_request=True)

    @routes.get("/place", summary="which lexicon modules can be placed in a configuration, and why not the rest (pbo place)")
    def get_place(request: Request, config: str | None = None, tasks: str | None = None, rtpu: str | None = None,
                  module: Annotated[list[str] | None, Query()] = None) -> Reply:
        try:
            subsystem = loaded(subsystem_file(request), "answer a placement query")
            members = [name.strip() for name in tasks.split(",") if name.strip()] if tasks is not None else None
            return Reply({"ok": True, **placement_report(subsystem, config, tasks=members, rtpu=rtpu, modules=module)})
        except NoFile as exc:
            return refusal(NO_RUN, str(exc))
        except ValueError as exc:
            return refusal(BAD_REQUEST, str(exc), bad_request=True)

    @routes.get("/dictionary", summary="the job dictionary: object types, jobs, applications, objects, with classes and edges")
    def get_dictionary(request: Request) -> Reply:
        try:
            return Reply({"ok": True, **job_dictionary(loaded(subsystem_file(request), "list the job dictionary"))})
        except NoFile as exc:
            return refusal(NO_RUN, str(exc))
        except ValueError as exc:
            return refusal(BAD_REQUEST, str(exc), bad_request=True)

    @routes.post("/gaps", summary="where a partial application's gaps are, and of which object type")
    def post_gaps(request: Request, body: GapsRequest) -> Reply:
        try:
            return Reply({"ok": True, **row_gaps(loaded(subsystem_file(request), "find the gaps"), body.row)})
        except NoFile as exc:
            return refusal(NO_RUN, str(exc))
        except ValueError as exc:
            return refusal(BAD_REQUEST, str(exc), bad_request=True)

    return routes


class GapsRequest(BaseModel):
    """The workspace's row of icons, left to right: names of jobs, applications and objects, or
    steps as a file writes them ({job: object name} or {job: {variable: value}})."""

    row: list[Any]
