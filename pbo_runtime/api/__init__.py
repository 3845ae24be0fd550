"""The local network API: the operator's verbs, the reports and live streams over HTTP and WebSocket.

`pbo hmi` serves it (`api.server`), on 127.0.0.1 with a random token by default. Its routes are
made from the command table (`supervisor.commands.VERBS`), so a verb the table gains is a route
with no change here; the streams read the table's lock-free snapshots (`table.svar`). The app
(`api.app.create_app`) reaches the run only through a `RunLink` (`api.link`), so tests drive it
in-process with a fake one. What it protects against and how: docs/live.md.
"""
