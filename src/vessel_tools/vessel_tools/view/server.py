"""The view's HTTP and WebSocket server: the page's own files, its JSON, the newest image, and live updates.

One ``websockets`` server on one port does both: a request to ``/ws`` becomes a WebSocket, every other GET is
answered from a fixed table of routes (``ROUTES``), so no path a client sends ever reaches the file system and
nothing outside the page's own assets is served. It runs in its own thread with its own asyncio loop; the ROS
side hands it finished JSON text with ``broadcast``, which only schedules work on that loop.

A slow or vanished client must never slow the graph nor the other clients: each has a bounded queue that its own
task drains; when it is full the oldest update is dropped (every update is a whole snapshot, so the newest is all a
client needs) and counted. Browsers are held to the page's own origin (a page elsewhere cannot read the stream).
"""

from __future__ import annotations

import asyncio
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

from vessel_common.errors import DataError
from vessel_tools.view.state import ViewState

STATIC_DIR = Path(__file__).resolve().parent / "static"
ROUTES = {"/": ("index.html", "text/html; charset=utf-8"), "/index.html": ("index.html", "text/html; charset=utf-8"),
          "/view.js": ("view.js", "text/javascript; charset=utf-8"), "/view.css": ("view.css", "text/css")}
"""Every static file the server can send: request path -> (file in ``static/``, content type)."""
SECURITY_HEADERS = [
    ("Cache-Control", "no-store"),
    ("X-Content-Type-Options", "nosniff"),
    ("Content-Security-Policy", "default-src 'self'; img-src 'self' data: blob:; connect-src 'self'; "
                                "frame-ancestors 'none'"),
]
QUEUE_SIZE = 4
MAX_CLIENTS = 64
SEND_BUFFER_BYTES = 256 * 1024
"""The kernel's send buffer per client (a few images): past it, and the queue, a stalled client loses updates."""


@dataclass
class Client:
    """One WebSocket client: its queue of updates and what it was sent and missed."""

    queue: asyncio.Queue
    sent: int = 0
    dropped: int = 0


@dataclass
class ServerStats:
    """Clients now, and updates sent and dropped over the server's life (dropped: a client's queue was full)."""

    clients: int = 0
    connected_total: int = 0
    refused: int = 0
    sent: int = 0
    dropped: int = 0
    per_client_dropped: list[int] = field(default_factory=list)


class ViewServer:
    """Serve the page and stream snapshots of ``state`` to every WebSocket client.

    ``on_drop(n)`` is told of each dropped update (the node counts them on ``/diagnostics``).
    """

    def __init__(self, state: ViewState, host: str = "127.0.0.1", port: int = 8080,
                 queue_size: int = QUEUE_SIZE, max_clients: int = MAX_CLIENTS,
                 on_drop: Callable[[int], None] | None = None):
        self.state = state
        self.host, self.port = host, int(port)
        self.queue_size, self.max_clients = int(queue_size), int(max_clients)
        self.on_drop = on_drop
        self.stats = ServerStats()
        self._clients: dict[object, Client] = {}
        self._assets = {path: ((STATIC_DIR / name).read_bytes(), kind) for path, (name, kind) in ROUTES.items()}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None

    # ------------------------------------------------------------------------------------------ life
    def start(self, timeout_s: float = 10.0) -> int:
        """Start serving in a thread; the port bound (useful with port 0). DataError when it cannot bind."""
        self._thread = threading.Thread(target=self._run, name="view-server", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise DataError(f"the view server did not start within {timeout_s:g} s")
        if self._error is not None:
            raise DataError(f"cannot serve on {self.host}:{self.port} ({self._error}): choose another --port "
                            "(or stop what uses it)")
        return self.port

    def stop(self) -> None:
        """Close every connection and the listening socket."""
        if self._loop is not None and self._stop is not None and self._loop.is_running():
            self._loop.call_soon_threadsafe(self._stop.set)
        if self._thread is not None:
            self._thread.join(timeout=10.0)

    @property
    def url(self) -> str:
        """The page's address."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._serve())
        except BaseException as error:
            self._error = error
            self._ready.set()
        finally:
            loop.close()

    async def _serve(self) -> None:
        from websockets.asyncio.server import serve

        self._stop = asyncio.Event()
        async with serve(self._handle, self.host, self.port, process_request=self._process_request,
                         compression=None, max_size=4096, max_queue=4, server_header=None) as server:
            self.port = server.sockets[0].getsockname()[1]
            self._ready.set()
            await self._stop.wait()

    # ------------------------------------------------------------------------------------------ broadcast
    def broadcast(self, text: str) -> None:
        """Queue a JSON update for every client (from any thread; returns at once). Encoded once for all."""
        self._broadcast((text.encode(), True))

    def broadcast_image(self, namespace: str, jpeg: bytes) -> None:
        """Queue a camera's JPEG for every client as one binary frame: a length byte, the namespace, the JPEG.

        Pushed on the WebSocket rather than fetched by each page, so twenty pages cost twenty sends of the same
        bytes, not twenty HTTP requests.
        """
        name = namespace.encode()[:255]
        self._broadcast((bytes([len(name)]) + name + jpeg, False))

    def _broadcast(self, item: tuple[bytes, bool]) -> None:
        loop = self._loop
        if loop is not None and loop.is_running() and self._clients:
            loop.call_soon_threadsafe(self._enqueue_all, item)

    def _enqueue_all(self, item: tuple[bytes, bool]) -> None:
        dropped = 0
        for client in self._clients.values():
            dropped += self._enqueue(client, item)
        if dropped:
            self.stats.dropped += dropped
            if self.on_drop is not None:
                self.on_drop(dropped)

    @staticmethod
    def _enqueue(client: Client, item: tuple[bytes, bool]) -> int:
        """Put ``item`` in a client's queue, dropping its oldest one when full; how many were dropped."""
        dropped = 0
        while client.queue.full():
            client.queue.get_nowait()
            client.dropped += 1
            dropped += 1
        client.queue.put_nowait(item)
        return dropped

    @property
    def clients(self) -> int:
        """WebSocket clients connected now."""
        return len(self._clients)

    # ------------------------------------------------------------------------------------------ websocket
    async def _handle(self, connection) -> None:
        if len(self._clients) >= self.max_clients:
            self.stats.refused += 1
            await connection.close(1013, "too many clients")
            return
        sock = connection.transport.get_extra_info("socket")
        if sock is not None:  # what a stalled client can hold in this machine's memory: bounded, not autotuned
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)
        client = Client(asyncio.Queue(self.queue_size))
        self._clients[connection] = client
        self.stats.connected_total += 1
        self.stats.clients = len(self._clients)
        self._enqueue(client, (self.state.snapshot_json().encode(), True))
        sender = asyncio.create_task(self._send_loop(connection, client))
        closed = asyncio.create_task(connection.wait_closed())
        try:
            await asyncio.wait({sender, closed}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            sender.cancel()
            closed.cancel()
            del self._clients[connection]
            self.stats.clients = len(self._clients)
            self.stats.per_client_dropped.append(client.dropped)

    async def _send_loop(self, connection, client: Client) -> None:
        from websockets.exceptions import ConnectionClosed

        try:
            while True:
                payload, is_text = await client.queue.get()
                await connection.send(payload, text=is_text)
                client.sent += 1
                self.stats.sent += 1
        except ConnectionClosed:
            return

    # ------------------------------------------------------------------------------------------ http
    def _process_request(self, connection, request):
        """Answer every plain GET from the route table; let ``/ws`` (same origin only) become a WebSocket."""
        parts = urlsplit(request.path)
        path = parts.path
        if path == "/ws":
            origin = request.headers.get("Origin")
            if origin is not None and urlsplit(origin).netloc != request.headers.get("Host", ""):
                return self._response(403, b"cross-origin WebSocket refused\n", "text/plain")
            return None
        if path in self._assets:
            body, kind = self._assets[path]
            return self._response(200, body, kind)
        return self._dynamic(path, parse_qs(parts.query))

    def _dynamic(self, path: str, query: dict[str, list[str]]):
        if path == "/vessels.json":
            return self._response(200, self.state.vessels_json().encode(), "application/json")
        if path == "/state.json":
            return self._response(200, self.state.snapshot_json().encode(), "application/json")
        if path == "/image.jpg":
            image = self.state.image(query.get("camera", [""])[0])
            if image is not None:
                return self._response(200, image[0], "image/jpeg")
        elif path == "/chart" and self.state.chart is not None:
            chart = self.state.chart
            return self._response(200, chart.image.read_bytes(), chart.content_type)
        elif path == "/favicon.ico":
            return self._response(204, b"", "image/x-icon")
        return self._response(404, b"not found\n", "text/plain")

    @staticmethod
    def _response(status: int, body: bytes, kind: str):
        from http import HTTPStatus

        from websockets.datastructures import Headers
        from websockets.http11 import Response

        headers = Headers([("Content-Type", kind), ("Content-Length", str(len(body))), ("Connection", "close"),
                           *SECURITY_HEADERS])
        return Response(status, HTTPStatus(status).phrase, headers, body)
