"""The token every request needs, and the Origin check of WebSocket upgrades: one dependency.

Jupyter's model: `pbo hmi` draws a random token (`new_token`) and prints it in the URL it
gives. A request shows it as `Authorization: Bearer TOKEN`, or in the cookie the first page
load with `?token=TOKEN` sets (HttpOnly, SameSite=Strict: scripts cannot read it and no other
site's page sends it), or as `?token=` itself. `require_token` checks it, compared in constant
time, on every route of the protected router (`api.app`): no route checks it itself.

A browser lets any page open a WebSocket to 127.0.0.1 and sends the cookie along, so an upgrade
whose Origin is not the server's own (http://HOST:PORT as the Host header gives it) is refused
as well: another site's page must not stream or command a run. Non-browser clients send no
Origin and are judged by the token alone.
"""

from __future__ import annotations

import secrets

from fastapi import HTTPException, WebSocketException, status
from starlette.requests import HTTPConnection

COOKIE = "pbo_token"
TOKEN_BYTES = 32  # 256 random bits, as URL-safe text (43 characters)


def new_token() -> str:
    return secrets.token_urlsafe(TOKEN_BYTES)


def presented_token(connection: HTTPConnection) -> str | None:
    """The token the request shows: the Authorization header, the cookie, or `?token=`."""
    scheme, _, credentials = connection.headers.get("authorization", "").partition(" ")
    if scheme.lower() == "bearer" and credentials:
        return credentials.strip()
    return connection.cookies.get(COOKIE) or connection.query_params.get("token")


def same_origin(connection: HTTPConnection) -> bool:
    """True when the request has no Origin (not a browser) or the server's own, as its Host header names it."""
    origin = connection.headers.get("origin")
    if origin is None:
        return True
    host = connection.headers.get("host", "")
    return bool(host) and origin.lower() in (f"http://{host}".lower(), f"https://{host}".lower())


def require_token(connection: HTTPConnection) -> None:
    """The router's one dependency: 401 (HTTP) or a refused upgrade (WebSocket, code 1008) without the right token."""
    expected: str = connection.app.state.token
    websocket = connection.scope["type"] == "websocket"
    if websocket and not same_origin(connection):
        origin = connection.headers.get("origin", "")[:60]
        raise WebSocketException(status.WS_1008_POLICY_VIOLATION, f"refused: origin {origin!r} is not this server's")
    given = presented_token(connection)
    if given is None or not secrets.compare_digest(given.encode(), expected.encode()):
        why = "a wrong token" if given is not None else "no token"
        message = (f"unauthorized: {why}; open the URL pbo hmi printed (it carries ?token=...), "
                   f"or send the header 'Authorization: Bearer TOKEN'")
        if websocket:  # a close reason holds at most 123 bytes
            raise WebSocketException(status.WS_1008_POLICY_VIOLATION, f"unauthorized: {why}")
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, message, headers={"WWW-Authenticate": "Bearer"})
