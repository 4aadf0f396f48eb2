"""``./vessel view`` in a real browser: headless Chromium driven by selenium loads the page from the running tool.

The fast test publishes synthetic track arrays from this process (the graph's message types, on the test's own
ROS domain) so what the page must show is known exactly; the slow one starts the real graph on video 13's bag
through ``view --source`` and takes the screenshot of docs/view.md. Both save their screenshot under out/view/.
Without Chromium and its driver (``apt-get install chromium chromium-driver``; ``./vessel test`` installs them)
or selenium (``requirements-view.txt``) they skip, saying so.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import subprocess
import time
import urllib.request
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
SCREENSHOTS = REPO / "out" / "view"


def _browser_paths() -> tuple[str, str] | str:
    chromium = os.environ.get("VESSEL_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
    driver = os.environ.get("VESSEL_CHROMEDRIVER") or shutil.which("chromedriver")
    if not chromium or not driver:
        return ("no headless browser: install Debian's chromium and chromium-driver (apt-get install -y chromium "
                "chromium-driver; ./vessel test does) or set VESSEL_CHROMIUM / VESSEL_CHROMEDRIVER")
    return chromium, driver


@pytest.fixture
def browser():
    """Headless Chromium under selenium, its console kept; skips where either is missing."""
    paths = _browser_paths()
    if isinstance(paths, str):
        pytest.skip(paths)
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is in requirements-view.txt: run "
                                    "./vessel setup --view")
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = paths[0]
    for argument in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                     "--window-size=1500,1000", "--hide-scrollbars"):
        options.add_argument(argument)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=options, service=Service(paths[1]))
    try:
        yield driver
    finally:
        driver.quit()


def console_errors(driver) -> list[str]:
    return [entry["message"] for entry in driver.get_log("browser") if entry["level"] == "SEVERE"]


def start_view(python_exe: str, env: dict, log: Path, *args: str) -> tuple[subprocess.Popen, str]:
    """``./vessel view --port 0 ARGS`` as its own process; it and the URL it serves on."""
    out = open(log, "w")
    process = subprocess.Popen([python_exe, "-m", "vessel_tools.cli", "view", "--port", "0", *args], env=env,
                               stdout=out, stderr=subprocess.STDOUT, cwd=REPO, start_new_session=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        found = re.search(r"serving (http://127\.0\.0\.1:\d+/)", log.read_text())
        if found:
            return process, found.group(1)
        if process.poll() is not None:
            break
        time.sleep(0.1)
    process.kill()
    pytest.fail(f"./vessel view did not start:\n{log.read_text()}")


def markers(driver) -> dict[str, tuple[float, float]]:
    """Every vessel drawn on the plan: id -> (east, north) as the page placed it."""
    return {k: tuple(v) for k, v in driver.execute_script(
        "const out = {}; for (const g of document.querySelectorAll('svg g[data-vessel-id]'))"
        " out[g.dataset.vesselId] = [Number(g.dataset.east), Number(g.dataset.north)]; return out;").items()}


def track_array(stamp_s: float, vessels: list[dict]):
    from vessel_msgs.msg import VesselTrack, VesselTrackArray

    array = VesselTrackArray()
    array.header.stamp.sec, array.header.stamp.nanosec = int(stamp_s), int(round(stamp_s % 1 * 1e9))
    array.header.frame_id = "camera"
    for spec in vessels:
        track = VesselTrack()
        track.header = array.header
        track.id, track.is_target, track.class_id, track.status = spec["id"], spec.get("target", False), "vessel", 1
        track.has_world = True
        track.position.x, track.position.y = spec["east"], spec["north"]
        track.velocity.x, track.velocity.y = 2.0, -1.0
        track.position_covariance = [400.0, 50.0, 50.0, 100.0]
        track.latitude, track.longitude = 32.70297 + spec["north"] / 111_195.0, -117.234631 + spec["east"] / 93_560.0
        track.distance_m = math.hypot(spec["east"], spec["north"])
        track.bearing_deg = math.degrees(math.atan2(spec["east"], spec["north"])) % 360.0
        track.bbox.center.position.x, track.bbox.center.position.y, track.bbox.size_x, track.bbox.size_y = (
            640.0, 420.0, 40.0, 20.0)
        if hasattr(track, "has_cpa"):
            track.has_cpa, track.cpa_m, track.tcpa_s = True, 80.0, 95.0
            track.cpa_alert = spec.get("target", False)
        array.tracks.append(track)
    return array


def annotated_image():
    import numpy as np
    from sensor_msgs.msg import Image

    image = Image()
    image.height, image.width, image.encoding, image.step = 180, 320, "bgr8", 320 * 3
    pixels = np.zeros((180, 320, 3), np.uint8)
    pixels[90:, :] = (90, 60, 20)  # sea below a horizon
    image.data = pixels.tobytes()
    return image


@pytest.fixture
def synthetic(ros_context, wait_until):
    """Publishers of the graph's outputs in this process, on the test's domain."""
    import rclpy
    from sensor_msgs.msg import Image

    from vessel_common.qos import SENSOR_DATA_QOS, reliable_qos
    from vessel_msgs.msg import VesselTrackArray

    node = rclpy.create_node("synthetic_graph", context=ros_context)
    publishers = {"tracks": node.create_publisher(VesselTrackArray, "/vessel/tracks", reliable_qos(10)),
                  "image": node.create_publisher(Image, "/vessel/detections/image", SENSOR_DATA_QOS)}
    yield publishers
    node.destroy_node()


def test_the_page_shows_the_vessels_live_and_they_move(ros_env, python_exe, tmp_path, browser, synthetic, wait_until,
                                                       interrupt):
    pytest.importorskip("foxglove", reason="foxglove-sdk is in requirements-view.txt: run ./vessel setup --view")
    process, url = start_view(python_exe, ros_env, tmp_path / "view.log", "--update-hz", "20", "--image-hz", "20",
                              "--foxglove-port", "0")
    try:
        assert "and Foxglove on ws://127.0.0.1:" in (tmp_path / "view.log").read_text()
        assert wait_until(lambda: synthetic["tracks"].get_subscription_count() > 0, 30), "the view never subscribed"
        synthetic["tracks"].publish(track_array(0.0, [{"id": "1", "east": 1.0, "north": 1.0}]))  # bad: counted
        synthetic["tracks"].publish(track_array(1000.0, [{"id": "7", "east": 120.0, "north": 300.0, "target": True},
                                                         {"id": "9", "east": -200.0, "north": 450.0}]))
        browser.get(url)
        assert wait_until(lambda: set(markers(browser)) == {"7", "9"}, 20), f"vessels drawn: {markers(browser)}"
        assert markers(browser)["7"] == (120.0, 300.0)
        assert browser.execute_script("return document.querySelector('g[data-vessel-id=\"7\"]').classList"
                                      ".contains('target')")
        assert "CPA 80 m" in browser.find_element("css selector", "g[data-vessel-id='7']").text
        before = browser.execute_script("return document.querySelector('g[data-vessel-id=\"9\"] .marker')"
                                        ".getAttribute('cx')")
        synthetic["tracks"].publish(track_array(1004.0, [{"id": "7", "east": 128.0, "north": 296.0, "target": True},
                                                         {"id": "9", "east": -150.0, "north": 450.0}]))
        assert wait_until(lambda: markers(browser).get("9") == (-150.0, 450.0), 20), "vessel 9 did not move"
        after = browser.execute_script("return document.querySelector('g[data-vessel-id=\"9\"] .marker')"
                                       ".getAttribute('cx')")
        assert float(after) != float(before)
        image_shown = "return !document.querySelector('img[data-role=\"image\"]').classList.contains('empty')"
        assert wait_until(lambda: browser.execute_script(image_shown), 20,
                          spin=lambda: (synthetic["image"].publish(annotated_image()), time.sleep(0.05)))
        vessels = json.loads(urllib.request.urlopen(url + "vessels.json", timeout=10).read())["vessels"]
        assert [(v["id"], v["east_m"], v["is_target"]) for v in vessels] == [("7", 128.0, True), ("9", -150.0, False)]
        state = json.loads(urllib.request.urlopen(url + "state.json", timeout=10).read())
        assert state["counts"]["bad_stamp"] == 1  # the bad array was counted and the view went on
        SCREENSHOTS.mkdir(parents=True, exist_ok=True)
        browser.save_screenshot(str(SCREENSHOTS / "synthetic.png"))
        assert console_errors(browser) == []
    finally:
        status = interrupt(process)
    assert status == 0, (tmp_path / "view.log").read_text()


def video_13_bag(request, tmp_path: Path) -> Path:
    """``bags/video_13``, else built from the challenge data into ``tmp_path`` (skips without either)."""
    bag = REPO / "bags" / "video_13"
    if (bag / "metadata.yaml").is_file():
        return bag
    data_dir = request.getfixturevalue("data_dir")  # skips, saying where it looked, without the data
    from vessel_tools.detect.bag_build import build_from_dataset

    build_from_dataset(data_dir, tmp_path / "bags", [13])
    return tmp_path / "bags" / "video_13"


@pytest.mark.slow
def test_view_replays_a_bag_through_the_graph(ros_env, python_exe, tmp_path, browser, wait_until, interrupt,
                                               request):
    bag = video_13_bag(request, tmp_path)
    log = tmp_path / "view.log"
    process, url = start_view(python_exe, ros_env, log, "--source", str(bag), "--rate", "4",
                              "--log-dir", str(tmp_path / "graph"))
    try:
        browser.get(url)
        assert wait_until(lambda: len(markers(browser)) > 0, 240), f"no vessel drawn:\n{log.read_text()}"
        first = markers(browser)
        assert wait_until(lambda: any(markers(browser).get(k, v) != v for k, v in first.items()), 60), \
            "no vessel moved"
        assert wait_until(lambda: browser.execute_script(
            "return document.querySelector('svg g.vessel.target') !== null && !document.querySelector("
            "'img[data-role=\"image\"]').classList.contains('empty') && Math.max(0, ...Array.from("
            "document.querySelectorAll('svg g.vessel.target polyline.track'), p => p.points.length)) >= 12"), 120), \
            "no vessel of interest with a track beside the camera image"
        vessels = json.loads(urllib.request.urlopen(url + "vessels.json", timeout=10).read())["vessels"]
        assert any(v["is_target"] and v["lat"] is not None for v in vessels)
        SCREENSHOTS.mkdir(parents=True, exist_ok=True)
        browser.save_screenshot(str(SCREENSHOTS / "video_13.png"))
        assert console_errors(browser) == []
    finally:
        status = interrupt(process, 30)
    assert status == 0, log.read_text()
