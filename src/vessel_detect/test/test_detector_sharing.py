"""The detectors of several cameras in one process: one model per model, one worker serving each camera in turn."""

from __future__ import annotations

import threading
import time

from vessel_detect.detector_sharing import SharedDetection
from vessel_detect.image_queue import ImageQueue


class _Camera:
    """A member: its own queue of the newest image, and what the shared worker did with its images."""

    def __init__(self, name: str, shared: SharedDetection, order: list, busy_s: float = 0.0):
        self.name, self.order, self.busy_s = name, order, busy_s
        self.queue = ImageQueue(1, lambda kind, message: message, on_put=shared.wake)

    def process_safely(self, item) -> None:
        time.sleep(self.busy_s)
        self.order.append((self.name, item.message))


def _wait_for(predicate, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.01)
    return predicate()


def test_one_model_is_opened_per_model_whoever_asks():
    shared, opened = SharedDetection(), []

    def open_model(name):
        opened.append(name)
        return object()

    first = shared.model(("a.onnx", 2), lambda: open_model("a"))
    assert shared.model(("a.onnx", 2), lambda: open_model("a")) is first
    assert shared.model(("a.onnx", 1), lambda: open_model("a1")) is not first
    assert opened == ["a", "a1"]


def test_the_worker_takes_each_cameras_newest_image_in_turn():
    """A camera sending fast cannot starve the others: each waiting camera gets one image per turn."""
    shared, order = SharedDetection(), []
    cameras = [_Camera(name, shared, order, busy_s=0.02) for name in ("a", "b", "c")]
    gate, holding = threading.Event(), threading.Event()
    blocker = _Camera("z", shared, order)

    def hold(item) -> None:  # holds the worker while the queues fill
        holding.set()
        gate.wait(5.0)

    blocker.process_safely = hold
    shared.join(blocker)
    blocker.queue.put("raw", "hold", 0.0)
    assert holding.wait(5.0)
    for camera in cameras:
        shared.join(camera)
    for frame in range(3):  # "a" replaces its own waiting image: only its newest is kept
        cameras[0].queue.put("raw", frame, 0.0)
    cameras[1].queue.put("raw", 10, 0.0)
    cameras[2].queue.put("raw", 20, 0.0)
    gate.set()
    assert _wait_for(lambda: len(order) == 3)
    assert sorted(order) == [("a", 2), ("b", 10), ("c", 20)]
    for member in (blocker, *cameras):
        member.queue.stop()
        shared.leave(member)
    assert shared._thread is None  # the worker ends with its last member
