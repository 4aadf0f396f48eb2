"""The images waiting for the detector's network: the newest kept, the next one decoded ahead.

The detector node's subscription callbacks ``put`` each image; its worker thread ``take``s them, oldest first, and
gets the pixels from ``QueuedImage.pixels``. Beyond ``capacity`` the oldest waiting image is dropped, so the
output never lags behind a live camera. With a decode-ahead thread running ``decode_ahead``, the image the worker
will take next is decoded while the worker runs the network on the current one, so decoding does not add to the
time per frame. It decodes at most one image per image taken, so a camera faster than the detector wastes at most
one decode per processed image (the one decoded ahead and then replaced by a newer image). A decode error is kept
with its image and raised to the worker when it asks for the pixels, as if the worker had decoded it.

ROS-free: ``decode`` is any function ``(kind, message) -> pixels`` that raises on a bad image.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable
from typing import Any

WAITING, DECODING, TAKEN = "waiting", "decoding", "taken"


class QueuedImage:
    """An image put in the queue, and its pixels once the decode-ahead thread has decoded them.

    ``state``: ``waiting``; then ``decoding`` (the decode-ahead thread took it; ``done`` is set when its pixels or
    its error are there) or ``taken`` (the worker decodes it itself). Changed under the queue's lock, and no more
    once the worker has taken the image.
    """

    __slots__ = ("kind", "message", "received", "state", "_decode", "_pixels", "_error", "_done")

    def __init__(self, kind: str, message: Any, received: float, decode: Callable[[str, Any], Any]) -> None:
        self.kind, self.message, self.received = kind, message, received
        self.state = WAITING
        self._decode = decode
        self._pixels = None
        self._error: Exception | None = None
        self._done = threading.Event()

    def pixels(self):
        """The decoded image: decoded here unless the decode-ahead thread did it (its error raised here).

        Handed over: the image keeps no reference to the pixels, so they go when the worker is done with them.
        """
        if self.state != DECODING:
            return self._decode(self.kind, self.message)
        self._done.wait()
        if self._error is not None:
            raise self._error
        pixels, self._pixels = self._pixels, None
        return pixels

    def _decode_now(self) -> None:
        try:
            self._pixels = self._decode(self.kind, self.message)
        except Exception as error:  # raised to the worker by pixels(), which counts it as the worker always did
            self._error = error
        finally:
            self._done.set()


class ImageQueue:
    """At most ``capacity`` images waiting, oldest dropped first; see the module docstring."""

    def __init__(self, capacity: int, decode: Callable[[str, Any], Any],
                 on_put: Callable[[], None] | None = None) -> None:
        if capacity < 1:
            raise ValueError(f"an image queue holds at least one image, got capacity {capacity}")
        self.capacity = capacity
        self._decode = decode
        self._on_put = on_put  # wakes a worker that serves several queues (``detector_sharing``)
        self._lock = threading.Condition()
        self._waiting: deque[QueuedImage] = deque()
        self._stopped = False
        self._ahead_allowed = False

    def put(self, kind: str, message: Any, received: float) -> int:
        """Add an image; returns how many images were dropped to make room for it (1: itself, once stopped)."""
        with self._lock:
            if self._stopped:
                return 1
            dropped = 0
            while len(self._waiting) >= self.capacity:
                self._waiting.popleft()
                dropped += 1
            self._waiting.append(QueuedImage(kind, message, received, self._decode))
            self._lock.notify_all()
        if self._on_put is not None:
            self._on_put()
        return dropped

    def take(self) -> QueuedImage | None:
        """The oldest waiting image, waiting for one; None once stopped. Allows one more decode ahead."""
        with self._lock:
            while not self._waiting and not self._stopped:
                self._lock.wait(0.5)
            if self._stopped:
                return None
            return self._take_locked()

    def take_nowait(self) -> QueuedImage | None:
        """The oldest waiting image, or None at once when there is none (or once stopped)."""
        with self._lock:
            if self._stopped or not self._waiting:
                return None
            return self._take_locked()

    def _take_locked(self) -> QueuedImage:
        """The oldest waiting image, taken (the lock held), allowing one more decode ahead."""
        image = self._waiting.popleft()
        if image.state == WAITING:
            image.state = TAKEN
        self._ahead_allowed = True
        self._lock.notify_all()
        return image

    def decode_ahead(self) -> None:
        """The decode-ahead thread's loop: decode the next image to be taken, once per image taken; until stopped."""
        while True:
            with self._lock:
                while not self._stopped and not (self._ahead_allowed and self._waiting
                                                 and self._waiting[0].state == WAITING):
                    self._lock.wait(0.5)
                if self._stopped:
                    return
                image = self._waiting[0]
                image.state = DECODING
                self._ahead_allowed = False
            image._decode_now()
            del image  # a dropped image's pixels must not wait here for the next decode

    def stop(self) -> int:
        """Wake and end ``take`` and ``decode_ahead``; returns how many waiting images were dropped."""
        with self._lock:
            self._stopped = True
            dropped = len(self._waiting)
            self._waiting.clear()
            self._lock.notify_all()
            return dropped
