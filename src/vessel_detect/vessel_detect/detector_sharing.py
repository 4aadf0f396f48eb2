"""One network and one worker for the detectors of several cameras in one process.

A detector per camera, each a process with its own onnxruntime session and worker thread, costs a camera the
session's memory and leaves the cameras' workers competing for the cores. The detector nodes of several cameras in
one process (``./vessel graph --processes per-role``) share instead: one session per model (``model``), and one
worker thread that takes the newest waiting image of each camera in turn (``join``), so every camera gets its turn
however fast another one sends. Each node keeps its own parameters, calibration, queue, publishers and counters.

ROS-free: a member is anything with an ``ImageQueue`` as ``queue`` and a ``process_safely(item)`` that never
raises.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Hashable
from typing import Any, Protocol


class Member(Protocol):
    """A detector served by the shared worker."""

    queue: Any

    def process_safely(self, item: Any) -> None:
        """Detect on one image and publish; counts its own problems, never raises."""


class SharedDetection:
    """The models and the one worker the detectors of a process share; see the module docstring."""

    def __init__(self) -> None:
        self._models: dict[Hashable, object] = {}
        self._models_lock = threading.Lock()
        self._members: list[Member] = []
        self._wake = threading.Condition()
        self._pending = False
        self._next = 0
        self._thread: threading.Thread | None = None

    def model(self, key: Hashable, open_model: Callable[[], object]) -> object:
        """The model of ``key`` (what names it and how it runs), opened by the first detector that asks."""
        with self._models_lock:
            if key not in self._models:
                self._models[key] = open_model()
            return self._models[key]

    def join(self, member: Member) -> None:
        """Serve ``member`` from now on (the worker starts with the first member)."""
        with self._wake:
            self._members.append(member)
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="detector-shared-worker", daemon=True)
                self._thread.start()
            self._wake.notify_all()

    def leave(self, member: Member) -> None:
        """Serve ``member`` no more (its queue is stopped by its node); the worker ends with the last member."""
        with self._wake:
            self._members = [m for m in self._members if m is not member]
            self._wake.notify_all()
        if not self._members and self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
            self._thread = None

    def wake(self) -> None:
        """An image was put in a member's queue (``ImageQueue``'s ``on_put``)."""
        with self._wake:
            self._pending = True
            self._wake.notify_all()

    def _take(self) -> tuple[Member, Any] | None:
        """The next member in turn that has an image waiting, and its image; None when none has one."""
        members = list(self._members)
        for offset in range(len(members)):
            index = (self._next + offset) % len(members)
            item = members[index].queue.take_nowait() if members[index].queue is not None else None
            if item is not None:
                self._next = index + 1
                return members[index], item
        return None

    def _run(self) -> None:
        while True:
            with self._wake:
                if not self._members:
                    return
                self._pending = False
            taken = self._take()
            if taken is not None:
                member, item = taken
                member.process_safely(item)
                continue
            with self._wake:
                if not self._pending and self._members:
                    self._wake.wait(0.5)
