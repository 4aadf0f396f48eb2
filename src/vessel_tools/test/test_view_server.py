"""The view's server without ROS: its own assets only, JSON, the image, and clients that read slowly or never."""

from __future__ import annotations

import asyncio
import json
import socket
import time
import urllib.request

import pytest

websockets = pytest.importorskip("websockets", reason="websockets is in requirements.txt: run ./vessel setup")

from vessel_tools.view.server import ViewServer  # noqa: E402
from vessel_tools.view.state import TrackRecord, ViewState  # noqa: E402


@pytest.fixture
def served():
    state = ViewState()
    state.update_tracks("", 10.0, [TrackRecord("1", 10.0, has_world=True, east=5.0, north=6.0, lat=32.7, lon=-117.2,
                                               covariance=(1.0, 0.0, 0.0, 1.0))], now=0.0)
    server = ViewServer(state, "127.0.0.1", 0, max_clients=30)
    server.start()
    yield state, server
    server.stop()


def get(server: ViewServer, path: str) -> tuple[int, bytes, dict]:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{server.port}{path}", timeout=10) as response:
            return response.status, response.read(), dict(response.headers)
    except urllib.error.HTTPError as error:
        return error.code, error.read(), dict(error.headers)


def raw_get(server: ViewServer, target: str) -> int:
    """The status of a request line sent as it is (no client normalises the path first)."""
    with socket.create_connection(("127.0.0.1", server.port), timeout=10) as sock:
        sock.sendall(f"GET {target} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
        reply = sock.recv(4096).decode(errors="replace")
    return int(reply.split()[1]) if reply.startswith("HTTP/1.1") else 0


def test_it_serves_the_page_its_assets_and_the_vessels(served):
    state, server = served
    status, body, headers = get(server, "/")
    assert status == 200 and b"<svg" in body and headers["Content-Type"].startswith("text/html")
    assert "default-src 'self'" in headers["Content-Security-Policy"]
    for path in ("/view.js", "/view.css"):
        assert get(server, path)[0] == 200
    status, body, _ = get(server, "/vessels.json")
    vessel = json.loads(body)["vessels"][0]
    assert status == 200 and (vessel["id"], vessel["east_m"], vessel["lat"]) == ("1", 5.0, 32.7)
    assert json.loads(get(server, "/state.json")[1])["type"] == "state"
    assert get(server, "/image.jpg")[0] == 404  # none yet
    state.set_image("", b"\xff\xd8jpeg", 10.0)
    status, body, headers = get(server, "/image.jpg?camera=&seq=1")
    assert (status, body, headers["Content-Type"]) == (200, b"\xff\xd8jpeg", "image/jpeg")
    assert get(server, "/favicon.ico")[0] == 204


@pytest.mark.parametrize("target", ["/../../etc/passwd", "/%2e%2e/%2e%2e/etc/passwd", "/static/view.js",
                                    "/view.js/../server.py", "/server.py", "/..%2fserver.py", "//etc/passwd",
                                    "/chart"])
def test_nothing_but_its_own_routes_is_served(served, target):
    _, server = served
    assert raw_get(server, target) == 404


def test_it_binds_to_this_machine_only_by_default():
    server = ViewServer(ViewState(), port=0)
    server.start()
    try:
        assert server.host == "127.0.0.1" and server.url == f"http://127.0.0.1:{server.port}/"
    finally:
        server.stop()


def test_a_port_in_use_is_one_clear_error(served):
    from vessel_common.errors import DataError

    _, server = served
    with pytest.raises(DataError, match="choose another --port"):
        ViewServer(ViewState(), port=server.port).start()


async def _clients(port: int, count: int, messages: int, server: ViewServer, size: int) -> dict:
    """``count`` clients, the first never reading; ``messages`` broadcasts of ``size`` bytes; what the others got."""
    from websockets.asyncio.client import connect

    uri = f"ws://127.0.0.1:{port}/ws"
    silent = socket.socket()
    silent.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # fills after a few updates, as a stalled tab
    silent.connect(("127.0.0.1", port))
    sockets = [await connect(uri, sock=silent, max_size=None)]
    sockets += [await connect(uri, max_size=None) for _ in range(count - 1)]
    deadline = time.monotonic() + 10
    while server.clients < count and time.monotonic() < deadline:
        await asyncio.sleep(0.01)
    last: dict[int, int] = {}

    async def read_until_last(index: int, ws) -> None:
        async for text in ws:
            if json.loads(text).get("seq") == messages - 1:
                last[index] = messages - 1
                return

    readers = asyncio.gather(*(read_until_last(i, ws) for i, ws in enumerate(sockets) if i))
    padding = "x" * size
    broadcast_s = 0.0
    for i in range(messages):  # at a pace the readers keep up with: only the silent client falls behind
        started = time.perf_counter()
        server.broadcast(json.dumps({"type": "state", "seq": i, "padding": padding}))
        broadcast_s = max(broadcast_s, time.perf_counter() - started)
        await asyncio.sleep(0.005)
    await asyncio.wait_for(readers, 60)
    for ws in sockets[1:]:
        await ws.close()
    sockets[0].transport.abort()  # a vanished client: no closing handshake
    return {"broadcast_s": broadcast_s, "readers_done": len(last)}


def test_twenty_clients_hold_and_one_that_never_reads_only_loses_its_own_updates(served):
    _, server = served
    result = asyncio.run(_clients(server.port, 20, 200, server, 32_000))
    assert result["readers_done"] == 19  # every reading client got the newest update
    assert result["broadcast_s"] < 0.25  # handing an update over never waits for a client
    deadline = time.monotonic() + 10
    while server.clients and time.monotonic() < deadline:
        time.sleep(0.02)
    drops = sorted(server.stats.per_client_dropped)
    assert server.stats.connected_total == 20 and sum(drops) == server.stats.dropped
    assert drops[-1] >= 100 and drops[-2] <= drops[-1] // 10  # the silent client lost updates, the others kept up


def test_images_go_to_every_page_as_one_binary_frame_with_their_camera(served):
    from websockets.asyncio.client import connect

    _, server = served

    async def run() -> bytes:
        async with connect(f"ws://127.0.0.1:{server.port}/ws") as ws:
            assert json.loads(await ws.recv())["type"] == "state"
            server.broadcast_image("left", b"\xff\xd8jpeg")
            return await asyncio.wait_for(ws.recv(), 10)

    assert asyncio.run(run()) == b"\x04left\xff\xd8jpeg"


def test_a_page_elsewhere_cannot_open_the_stream_and_extra_clients_are_refused():
    from websockets.asyncio.client import connect
    from websockets.exceptions import ConnectionClosed, InvalidStatus

    server = ViewServer(ViewState(), port=0, max_clients=1)
    server.start()

    async def run() -> None:
        uri = f"ws://127.0.0.1:{server.port}/ws"
        with pytest.raises(InvalidStatus) as refused:
            await connect(uri, origin="http://elsewhere.example")
        assert refused.value.response.status_code == 403
        async with connect(uri, origin=f"http://127.0.0.1:{server.port}") as first:
            await first.recv()
            second = await connect(uri)
            with pytest.raises(ConnectionClosed) as closed:
                await second.recv()
            assert closed.value.rcvd.code == 1013

    try:
        asyncio.run(run())
        assert server.stats.refused == 1
    finally:
        server.stop()
