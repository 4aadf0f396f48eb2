"""The Foxglove bridge: the view's data advertised and sent in Foxglove's schemas, and the layout in the repo."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

pytest.importorskip("foxglove", reason="foxglove-sdk is in requirements-view.txt: run ./vessel setup --view")

from vessel_tools.view.foxglove_bridge import FoxgloveBridge, foxglove_layout, vessel_topic
from vessel_tools.view.geometry import load_geometry
from vessel_tools.view.state import TrackRecord

REPO = Path(__file__).resolve().parents[3]


def test_the_layout_in_the_repository_is_the_one_the_bridge_writes():
    assert (REPO / "config" / "foxglove_layout.json").read_text() == foxglove_layout(), \
        "rewrite it: ./vessel view --foxglove-layout config/foxglove_layout.json"
    layout = json.loads(foxglove_layout())
    panels = json.dumps(layout)
    assert all(f'"panelType": "{kind}"' in panels for kind in ("Map", "Image", "ThreeDee"))


async def _session(bridge: FoxgloveBridge, publish) -> tuple[dict, bytes]:
    from websockets.asyncio.client import connect

    async with connect(f"ws://127.0.0.1:{bridge.port}", subprotocols=["foxglove.sdk.v1"]) as ws:
        channels: dict[str, dict] = {}
        subscribed = False
        for _ in range(100):  # publish until the vessel's channel is advertised and one of its messages arrives
            publish()
            try:
                message = await asyncio.wait_for(ws.recv(), 0.2)
            except TimeoutError:
                continue
            if isinstance(message, bytes):
                return channels, message
            message = json.loads(message)
            if message["op"] == "advertise":
                channels.update({c["topic"]: c for c in message["channels"]})
            if not subscribed and vessel_topic("7") in channels:
                await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                    {"id": 1, "channelId": channels[vessel_topic("7")]["id"]}]}))
                subscribed = True
        raise AssertionError(f"no message of {vessel_topic('7')}; channels advertised: {sorted(channels)}")


def test_vessels_plan_boxes_and_image_go_out_in_foxglove_schemas():
    bridge = FoxgloveBridge(port=0)
    geometry = load_geometry(REPO / "config" / "aitas_camera.yaml")
    record = TrackRecord("7", 1000.0, is_target=True, has_world=True, east=100.0, north=200.0, vx=1.0, vy=0.5,
                         covariance=(25.0, 1.0, 1.0, 4.0), lat=32.7048, lon=-117.2335, bbox=(640, 400, 40, 20),
                         has_cpa=True, cpa_m=50.0, tcpa_s=120.0)

    def publish() -> None:
        bridge.publish_tracks(1000.0, [record], {"7": [(90.0, 195.0), (100.0, 200.0)]}, geometry)
        bridge.publish_image(1000.0, b"\xff\xd8\xff", "jpeg")
        bridge.publish_status({"line": "4.0 frames/s", "level": "ok"})

    try:
        channels, data = asyncio.run(_session(bridge, publish))
    finally:
        bridge.close()
    schemas = {topic: channel["schemaName"] for topic, channel in channels.items()}
    assert schemas["/view/plan"] == "foxglove.SceneUpdate"
    assert schemas["/view/image/annotations"] == "foxglove.ImageAnnotations"
    assert schemas["/view/image"] == "foxglove.CompressedImage"
    assert schemas["/view/target"] == schemas["/view/vessel/7"] == "foxglove.LocationFix"
    assert schemas["/view/status"] == "vessel_view.Status"
    assert data[0] == 1 and int.from_bytes(data[1:5], "little") == 1  # a message of subscription 1


def test_a_vessel_gone_closes_its_channel():
    bridge = FoxgloveBridge(port=0)
    try:
        record = TrackRecord("3", 5.0, has_world=True, east=1.0, north=2.0, lat=32.7, lon=-117.2)
        bridge.publish_tracks(5.0, [record], {}, None)
        assert set(bridge.vessels) == {"3"}
        bridge.publish_tracks(6.0, [], {}, None)
        assert bridge.vessels == {}
    finally:
        bridge.close()
