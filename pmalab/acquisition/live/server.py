"""The live view's local web server (stdlib ``ThreadingHTTPServer``, Server-Sent Events).

Routes: ``GET /`` the page; ``GET /assets/NAME`` its script, style and the vendored uPlot
(shipped in the package: no internet needed); ``GET /events[?run=N]`` the event stream
(:mod:`.hub`; without ``run`` it follows the newest run); ``POST /stop`` asks the runner
for the safe abort of Ctrl-C.

Stop is accepted only from a loopback client address (127.0.0.1, checked on the socket,
not from any header), only as POST with the header ``X-Pmalab-Stop: 1`` (a cross-site
form cannot set it, so another web page open in the same browser cannot stop the run) and
with a loopback ``Host`` (against DNS rebinding); anything else gets 403.

Each browser is served by its own thread, which only ever waits on the hub's condition
and writes to its own socket (5 s send timeout): a stalled or vanished browser ends its
thread and costs the recording nothing.
"""

from __future__ import annotations

import contextlib
import json
import socket
import threading
import time
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from urllib.parse import parse_qs, urlsplit

from pmalab.acquisition.live.address import is_loopback, url_host
from pmalab.acquisition.live.hub import Cursor, Hub
from pmalab.errors import ConfigError

#: files served under /assets/ (nothing else is readable through the server)
ASSETS = {
    "live.js": "text/javascript; charset=utf-8",
    "live.css": "text/css; charset=utf-8",
    "uPlot.iife.min.js": "text/javascript; charset=utf-8",
    "uPlot.min.css": "text/css; charset=utf-8",
    "uPlot.LICENSE.txt": "text/plain; charset=utf-8",
}
#: a comment line every this many seconds keeps proxies and browsers from timing out
KEEPALIVE_S = 10.0
SEND_TIMEOUT_S = 5.0
LOOPBACK_HOSTS = {"127.0.0.1", "localhost", "[::1]", "::1"}


def asset(name: str) -> bytes:
    """A file of the page, from the installed package."""
    return resources.files("pmalab.acquisition.live").joinpath("assets", name).read_bytes()


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True
    hub: Hub
    on_stop: Callable[[], str] | None
    closing: threading.Event


class _Handler(BaseHTTPRequestHandler):
    server: _Server
    protocol_version = "HTTP/1.1"
    server_version = "pmalab-live"

    def log_message(self, format: str, *args: object) -> None:
        pass  # the terminal belongs to the runner's progress and messages

    # ------------------------------------------------------------------ GET
    def do_GET(self) -> None:
        url = urlsplit(self.path)
        if url.path in ("/", "/index.html"):
            self._send(200, asset("index.html"), "text/html; charset=utf-8")
        elif url.path.startswith("/assets/") and url.path[8:] in ASSETS:
            name = url.path[8:]
            self._send(200, asset(name), ASSETS[name])
        elif url.path == "/events":
            self._events(parse_qs(url.query))
        else:
            self._send(404, b"not found\n", "text/plain")

    def _send(self, code: int, body: bytes, ctype: str) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _events(self, query: dict[str, list[str]]) -> None:
        hub = self.server.hub
        cur = Cursor()
        run = query.get("run", [""])[0]
        if run.isdigit():
            cur.follow, cur.run = False, int(run)
        self.connection.settimeout(SEND_TIMEOUT_S)
        self.close_connection = True
        self.send_response(200)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.send_header("Connection", "close")
        self.end_headers()
        allowed = self.server.on_stop is not None and is_loopback(self.client_address[0])
        seen = -1
        with hub.cond:
            hub.clients += 1
        try:
            self.wfile.write(hub.hello_for(allowed))
            while True:
                data = hub.updates(cur)
                if data:
                    self.wfile.write(data)
                    self.wfile.flush()
                if cur.ended or self.server.closing.is_set():
                    return
                version = hub.wait(seen, KEEPALIVE_S)
                if version == seen:
                    self.wfile.write(b": keepalive\n\n")
                seen = version
        except (OSError, ValueError):  # browser gone, stalled past the timeout, or closed
            return
        finally:
            with hub.cond:
                hub.clients -= 1

    # ------------------------------------------------------------------ POST
    def do_POST(self) -> None:
        if urlsplit(self.path).path != "/stop":
            self._json(404, {"ok": False, "message": "not found"})
            return
        length = int(self.headers.get("Content-Length") or 0)
        if 0 < length <= 4096:
            self.rfile.read(length)
        client = self.client_address[0]
        host = (self.headers.get("Host") or "").rsplit(":", 1)[0]
        if not is_loopback(client):
            self._json(
                403,
                {
                    "ok": False,
                    "message": f"stop is accepted only from 127.0.0.1 "
                    f"(this request came from {client})",
                },
            )
        elif host not in LOOPBACK_HOSTS or self.headers.get("X-Pmalab-Stop") != "1":
            self._json(403, {"ok": False, "message": "stop refused: not sent by the live page"})
        elif self.server.on_stop is None:
            self._json(409, {"ok": False, "message": "nothing to stop: viewing a file"})
        else:
            self._json(202, {"ok": True, "message": self.server.on_stop()})

    def _json(self, code: int, payload: dict[str, object]) -> None:
        self.close_connection = True
        self._send(code, json.dumps(payload).encode(), "application/json")


class LiveServer:
    """Serves ``hub`` on ``host:port`` from a background thread (port 0: any free one)."""

    def __init__(
        self,
        hub: Hub,
        host: str,
        port: int,
        on_stop: Callable[[], str] | None = None,
        option: str = "--live",
    ) -> None:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        server_cls = type("_Srv", (_Server,), {"address_family": family})
        try:
            self.httpd: _Server = server_cls((host, port), _Handler)
        except OSError as exc:
            reason = exc.strerror or str(exc)
            raise ConfigError(
                f"{option} {host}:{port}: cannot serve the live view: {reason}"
            ) from None
        self.httpd.hub = hub
        self.httpd.on_stop = on_stop
        self.httpd.closing = threading.Event()
        self.host = host
        self.port = int(self.httpd.server_address[1])
        self._thread = threading.Thread(
            target=self.httpd.serve_forever,
            kwargs={"poll_interval": 0.2},
            name="pmalab-live-http",
            daemon=True,
        )

    @property
    def url(self) -> str:
        return f"http://{url_host(self.host)}:{self.port}/"

    def start(self) -> str:
        self._thread.start()
        return self.url

    def close(self, grace_s: float = 1.0) -> None:
        """Stop accepting, give the event streams up to ``grace_s`` to send what is
        pending (the ``end`` event), close."""
        hub = self.httpd.hub
        deadline = time.monotonic() + grace_s
        with hub.cond:  # each stream leaves once it has sent the end event
            while hub.clients and hub.end_message is not None and time.monotonic() < deadline:
                hub.cond.wait(0.05)
        self.httpd.closing.set()
        with self.httpd.hub.cond:
            self.httpd.hub.cond.notify_all()
        with contextlib.suppress(Exception):
            self.httpd.shutdown()
        self.httpd.server_close()
