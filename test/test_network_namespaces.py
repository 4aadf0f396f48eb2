"""The graph split across two network namespaces joined by a veth pair publishes what one host publishes.

Camera and detector in one namespace, tracker, fuser, GPS publisher and recorder in the other, as on a vessel
whose camera computer is not the one that tracks. Needs root (network namespaces); skips with a message elsewhere.
The addresses are the test's own, inside namespaces it creates and removes.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time

import pytest

from vessel_fixtures.challenge_bags import build_video_bags

pytestmark = [pytest.mark.ros, pytest.mark.data, pytest.mark.slow]


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, check=check, timeout=30)


@pytest.fixture
def namespaces():
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("network namespaces need root and iproute2 (`ip`): not available here")
    tag = f"vt{os.getpid() % 100000}"
    names = (f"{tag}a", f"{tag}b")
    try:
        for name in names:
            _ip("netns", "add", name)
        _ip("link", "add", f"{tag}va", "type", "veth", "peer", "name", f"{tag}vb")
        for index, (name, link) in enumerate(zip(names, (f"{tag}va", f"{tag}vb"), strict=True)):
            _ip("link", "set", link, "netns", name)
            _ip("netns", "exec", name, "ip", "addr", "add", f"10.231.{os.getpid() % 200}.{index + 1}/24", "dev", link)
            _ip("netns", "exec", name, "ip", "link", "set", "lo", "up")
            _ip("netns", "exec", name, "ip", "link", "set", link, "up")
            _ip("netns", "exec", name, "ip", "route", "add", "224.0.0.0/4", "dev", link)  # DDS discovery
    except (subprocess.CalledProcessError, OSError) as error:
        for name in names:
            _ip("netns", "del", name, check=False)
        pytest.skip(f"cannot make network namespaces here ({error}): run as root on Linux")
    yield names
    for name in names:
        _ip("netns", "del", name, check=False)


def _fixes(recording) -> list[tuple[int, float, float, int]]:
    from vessel_detect.bag_reader import BagReader

    with BagReader(recording) as reader:
        return [(m.log_time_ns, fix.latitude, fix.longitude, fix.status.status)
                for m in reader.messages(["/vessel/fix"]) for fix in [reader.decode(m)]]


def test_two_namespaces_publish_the_fixes_of_one_host(namespaces, data_dir, model_path, ros_env, tmp_path):
    env = {k: v for k, v in ros_env.items() if k != "ROS_AUTOMATIC_DISCOVERY_RANGE"}  # across the veth: subnet
    bags = build_video_bags(data_dir, tmp_path / "bags", "14", env=env)
    bag = str(bags / "video_14")
    one_host = tmp_path / "one_host"
    single = subprocess.run([sys.executable, "-m", "vessel_bringup.graph", "--source", bag, "--rate", "0",
                             "--exit-at-end", "--record", str(one_host)], env=ros_env, capture_output=True,
                            text=True, timeout=600)
    assert single.returncode == 0, single.stderr[-3000:]

    split = tmp_path / "split"
    tracking = subprocess.Popen(
        ["ip", "netns", "exec", namespaces[1], sys.executable, "-m", "vessel_bringup.graph", "--source", bag,
         "--nodes", "tracker,fuser,gps_publisher", "--record", str(split), "--log-dir", str(tmp_path / "logs_b")],
        env=env, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(15.0)  # the tracking side is up and discoverable before a frame is sent
        camera_side = subprocess.run(
            ["ip", "netns", "exec", namespaces[0], sys.executable, "-m", "vessel_bringup.graph", "--source", bag,
             "--rate", "0", "--exit-at-end", "--nodes", "camera,detector", "--log-dir", str(tmp_path / "logs_a")],
            env=env, capture_output=True, text=True, timeout=600)
        assert camera_side.returncode == 0, camera_side.stderr[-3000:]
        time.sleep(5.0)
    finally:
        tracking.send_signal(2)
        tracking.communicate(timeout=60)
    import numpy as np

    expected, got = np.array(_fixes(one_host), dtype=float), np.array(_fixes(split), dtype=float)
    assert len(expected) == 36
    # Bit-identical: the same stamps, positions and status (NO_FIX frames carry NaN positions on both).
    missing = sorted(set(expected[:, 0]) - set(got[:, 0]))
    assert not missing, (f"{len(missing)} of {len(expected)} frames never reached the tracking side: "
                         f"{[int(m) for m in missing]} (first {int(expected[0, 0])}, last {int(expected[-1, 0])})")
    assert got.shape == expected.shape and np.array_equal(got, expected, equal_nan=True)
