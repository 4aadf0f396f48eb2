"""The detector's image queue: the newest kept, the next decoded ahead once per image taken, errors kept."""

import threading
import time

import pytest

from vessel_detect.image_queue import DECODING, TAKEN, ImageQueue


class Decoder:
    """Counts its calls; decoding ``"bad"`` raises; ``gate`` holds a decode until the test lets it go."""

    def __init__(self) -> None:
        self.calls: list[str] = []
        self.gate = threading.Event()
        self.gate.set()
        self.lock = threading.Lock()

    def __call__(self, kind: str, message: str) -> str:
        with self.lock:
            self.calls.append(message)
        self.gate.wait(10.0)
        if message == "bad":
            raise ValueError("bad bytes")
        return f"pixels of {message}"


def wait_until(predicate, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.005)
    return predicate()


@pytest.fixture
def ahead():
    """A queue of capacity 1 with its decode-ahead thread running."""
    decoder = Decoder()
    queue = ImageQueue(1, decoder)
    thread = threading.Thread(target=queue.decode_ahead, daemon=True)
    thread.start()
    yield queue, decoder
    queue.stop()
    thread.join(5.0)
    assert not thread.is_alive()


def test_without_the_decode_ahead_thread_the_worker_decodes_and_the_newest_image_replaces_the_older():
    decoder = Decoder()
    queue = ImageQueue(1, decoder)
    assert queue.put("compressed", "a", 0.0) == 0
    assert queue.put("compressed", "b", 1.0) == 1  # a is dropped: the output must not lag behind the camera
    image = queue.take()
    assert (image.message, image.received, image.state) == ("b", 1.0, TAKEN)
    assert decoder.calls == []
    assert image.pixels() == "pixels of b" and decoder.calls == ["b"]


def test_two_waiting_keeps_both_in_order():
    queue = ImageQueue(2, Decoder())
    assert [queue.put("raw", m, 0.0) for m in ("a", "b", "c")] == [0, 0, 1]
    assert [queue.take().message for _ in range(2)] == ["b", "c"]


def test_the_next_image_is_decoded_ahead_while_the_worker_works_and_not_decoded_again(ahead):
    queue, decoder = ahead
    queue.put("compressed", "a", 0.0)
    first = queue.take()  # nothing waits behind it: nothing is decoded ahead yet
    queue.put("compressed", "b", 1.0)
    assert wait_until(lambda: decoder.calls == ["b"]), decoder.calls  # decoded while the worker holds "a"
    assert first.pixels() == "pixels of a"
    second = queue.take()
    assert second.state == DECODING and second.pixels() == "pixels of b"
    assert decoder.calls == ["b", "a"]  # b once, by the decode-ahead thread


def test_at_most_one_image_is_decoded_ahead_per_image_taken(ahead):
    queue, decoder = ahead
    queue.put("compressed", "a", 0.0)
    queue.take()
    for message in ("b", "c", "d"):  # a camera faster than the detector: each replaces the one before
        queue.put("compressed", message, 0.0)
        time.sleep(0.05)
    assert decoder.calls == ["b"]  # c and d wait undecoded; the worker decodes the one it takes
    image = queue.take()
    assert image.message == "d" and image.state == TAKEN and image.pixels() == "pixels of d"


def test_the_worker_waits_for_a_decode_under_way_instead_of_decoding_twice(ahead):
    queue, decoder = ahead
    queue.put("compressed", "a", 0.0)
    queue.take()
    decoder.gate.clear()
    queue.put("compressed", "b", 0.0)
    assert wait_until(lambda: decoder.calls == ["b"])
    image = queue.take()
    result = []
    worker = threading.Thread(target=lambda: result.append(image.pixels()))
    worker.start()
    time.sleep(0.05)
    assert result == []  # still decoding
    decoder.gate.set()
    worker.join(5.0)
    assert result == ["pixels of b"] and decoder.calls == ["b"]


def test_a_decode_error_ahead_reaches_the_worker_as_if_it_had_decoded_the_image(ahead):
    queue, decoder = ahead
    queue.put("compressed", "a", 0.0)
    queue.take()
    queue.put("compressed", "bad", 0.0)
    assert wait_until(lambda: decoder.calls == ["bad"])
    image = queue.take()
    with pytest.raises(ValueError, match="bad bytes"):
        image.pixels()


def test_stop_ends_a_waiting_take():
    queue = ImageQueue(1, Decoder())
    taken = []
    worker = threading.Thread(target=lambda: taken.append(queue.take()))
    worker.start()
    time.sleep(0.05)
    queue.stop()
    worker.join(5.0)
    assert taken == [None]


def test_a_queue_holds_at_least_one_image():
    with pytest.raises(ValueError, match="at least one image"):
        ImageQueue(0, Decoder())
