"""`pbo hmi`: serve the local API on 127.0.0.1 with a fresh token, and say where.

The socket is bound here, before uvicorn starts, so `--port 0` (any free port) prints the port
it got, and a port in use is refused with a one-line message before anything is served. An
address other than loopback is refused, with the risk said, unless `--allow-remote` is given.
"""

from __future__ import annotations

import errno
import ipaddress
import socket
from collections.abc import Callable

import uvicorn
import yaml

from pbo_runtime.api.app import create_app
from pbo_runtime.api.auth import new_token
from pbo_runtime.api.link import LiveRunLink, NoRun
from pbo_runtime.config.file_kind import is_application_file
from pbo_runtime.errors import PboError

DEFAULT_PORT = 8470
LOOPBACK = "127.0.0.1"


def bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket on (host, port); PboError saying what to change when the OS refuses."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
        sock.listen(128)
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRINUSE:
            raise PboError(
                f"port {port} on {host} is in use (another pbo hmi?): pass --port N, or --port 0 for any free one"
            ) from None
        raise PboError(
            f"cannot listen on {host}:{port}: {exc.strerror or exc}; pass --host {LOOPBACK} or another --port"
        ) from None
    sock.set_inheritable(True)
    return sock


def is_loopback(host: str) -> bool:
    """Whether `host` names this machine only: localhost, 127.0.0.0/8, ::1."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False  # a host name: it may resolve to any interface


def remote_risk(host: str) -> str:
    return (f"listening on {host} lets other machines reach the API: anyone who can reach the port and has the token "
            f"can command the run, and the token crosses the network in clear text (plain HTTP); prefer --host "
            f"{LOOPBACK} and an SSH tunnel (see docs/live.md#security)")


def url(host: str, port: int, token: str) -> str:
    """The URL to open: the loopback address when the server listens on every interface."""
    shown = LOOPBACK if host in ("0.0.0.0", "") else ("[::1]" if host == "::" else (f"[{host}]" if ":" in host else host))
    return f"http://{shown}:{port}/?token={token}"


def describe_run(link: LiveRunLink) -> str:
    """What the API is attached to now, for the start-up lines."""
    try:
        subsystem, run_id, _table = link.find()
    except NoRun as exc:
        if link.run is None and (
            "no subsystem is running" in str(exc) or f"subsystem '{link.subsystem}' is not running" in str(exc)
        ):
            which = f"'{link.subsystem}'" if link.subsystem else "any subsystem"
            return (f"no run of {which} yet: lexicon, check, bus and graph are served, and a run started later "
                    f"is found at the next request")
        if link.run is None and exc.several:  # the server starts: the run meant is found at each request
            return (f"{exc}; until one is the only one, lexicon, check, bus and graph are served and a request "
                    f"for the run says which are alive")
        raise
    return f"attached to '{subsystem}' run {run_id}"


def subsystem_of(file: str) -> str | None:
    """The subsystem a file names (its top-level `subsystem:`), None when it names none it can read."""
    try:
        with open(file, encoding="utf-8") as stream:
            document = yaml.safe_load(stream)
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return None  # the checker route says what is wrong with it
    name = document.get("subsystem") if isinstance(document, dict) else None
    return name if isinstance(name, str) else None


def serve(file: str | None, host: str, port: int, subsystem: str | None, run: str | None,
          say: Callable[[str], None], warn: Callable[[str], None], allow_remote: bool = False) -> int:
    """Serve until Ctrl-C; the exit status. PboError (exit 2) when the run meant is not there or the port is taken.

    Given FILE and no --subsystem or --run, the run served is the one of FILE's subsystem (an application
    file's: each of its subsystems', by name, as the page asks: api.application). A host
    that is not loopback is refused (exit 1) unless `allow_remote`.
    """
    if not is_loopback(host) and not allow_remote:
        warn(f"error: {remote_risk(host)}; to accept that, give --allow-remote")
        return 1
    application = file is not None and subsystem is None and run is None and is_application_file(file)
    if file is not None and subsystem is None and run is None and not application:
        subsystem = subsystem_of(file)
    link = LiveRunLink(subsystem, run)
    # an application file: the page reads each subsystem's run by its name (api.application), and may start one
    attached = "application file: its subsystems' runs are found by their names" if application else describe_run(link)
    token = new_token()
    sock = bind(host, port)
    port = sock.getsockname()[1]
    if not is_loopback(host):
        warn(f"warning: {remote_risk(host)}")
    say(f"pbo hmi: {attached}; Ctrl-C stops the server (not the run); open:")
    say(url(host, port, token))
    app = create_app(link, token, file)
    config = uvicorn.Config(app, log_level="warning", access_log=False, lifespan="off", ws="websockets-sansio")
    try:
        uvicorn.Server(config).run(sockets=[sock])
    finally:
        sock.close()
        if app.state.application_run is not None:  # a run the page started ends with the server
            app.state.application_run.stop()
    return 0
