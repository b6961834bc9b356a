"""The replay served on a loopback address: ``phri view`` without ``--html``. One page per episode
(``/`` for a single log; a list of the study's episodes at ``/`` and each at ``/episode/NAME``),
made when asked for. Nothing listens beyond loopback: the address is checked before binding."""

from __future__ import annotations

import html
import logging
import threading
from collections.abc import Callable
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import unquote, urlsplit

from phri._validate import check_loopback
from phri.exceptions import InvalidParameterError, PhriError

__all__ = ["ReplayServer"]

log = logging.getLogger("phri.view")

#: A page by path: returns the HTML, or None for "no such page" (404).
Pages = Callable[[str], "str | None"]


class ReplayServer:
    """Serves `pages` on `host` (a loopback address 127.x.y.z) and `port` (0: any free one) in a
    thread; use as a context manager, or call :meth:`serve_forever` (Ctrl-C stops it)."""

    def __init__(self, pages: Pages, host: str = "127.0.0.1", port: int = 0) -> None:
        check_loopback(host)
        if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
            raise InvalidParameterError(f"port must be an integer in [0, 65535], got {port!r}")
        handler = _handler(pages)
        self._server = ThreadingHTTPServer((host, port), handler)
        self._server.daemon_threads = True
        self._thread: threading.Thread | None = None

    @property
    def address(self) -> tuple[str, int]:
        """The (host, port) bound: the port the system chose when 0 was asked for."""
        host, port = self._server.server_address[:2]
        return str(host), int(port)

    @property
    def url(self) -> str:
        """The address of the root page, ``http://host:port/``."""
        host, port = self.address
        return f"http://{host}:{port}/"

    def start(self) -> ReplayServer:
        """Serve in a background thread until :meth:`stop`; returns the server."""
        self._thread = threading.Thread(target=self._server.serve_forever, name="phri-view", daemon=True)
        self._thread.start()
        return self

    def serve_forever(self) -> None:
        """Serve in this thread until interrupted (KeyboardInterrupt), then close the socket."""
        try:
            self._server.serve_forever()
        finally:
            self._server.server_close()

    def stop(self) -> None:
        """Stop the background thread, if any, and close the socket."""
        if self._thread is not None:
            self._server.shutdown()
            self._thread.join()
            self._thread = None
        self._server.server_close()

    def __enter__(self) -> ReplayServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _handler(pages: Pages) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 (http.server's name)
            path = unquote(urlsplit(self.path).path)
            try:
                page = pages(path)
            except PhriError as e:
                body = f"<!doctype html><meta charset=utf-8><p>phri view: {html.escape(str(e))}</p>"
                self._send(HTTPStatus.UNPROCESSABLE_ENTITY, body)
                return
            if page is None:
                self._send(HTTPStatus.NOT_FOUND, "<!doctype html><meta charset=utf-8><p>no such page</p>")
                return
            self._send(HTTPStatus.OK, page)

        def _send(self, status: HTTPStatus, body: str) -> None:
            data = body.encode("utf-8")
            self.send_response(status)
            self.send_header("Content-Type", "text/html; charset=utf-8")
            self.send_header("Content-Length", str(len(data)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(data)

        def log_message(self, format: str, *args: object) -> None:  # noqa: A002 (http.server's name)
            log.debug("%s %s", self.address_string(), format % args)

    return Handler
