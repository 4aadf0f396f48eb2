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


def put_after_a_take(queue: ImageQueue, decoder: Decoder, message: str, hold: bool = False) -> None:
    """Take one image (which allows one decode ahead), put ``message`` and wait until its decode ahead has begun.

    ``hold``: the decode stays under way until the test sets ``decoder.gate``.
    """
    queue.put("compressed", "first", 0.0)
    queue.take()
    if hold:
        decoder.gate.clear()
    queue.put("compressed", message, 0.0)
    assert wait_until(lambda: decoder.calls == [message]), decoder.calls


def decoding_ahead(capacity: int = 1):
    """A queue with its decode-ahead thread running, the decoder, and the thread."""
    decoder = Decoder()
    queue = ImageQueue(capacity, decoder)
    thread = threading.Thread(target=queue.decode_ahead, daemon=True)
    thread.start()
    return queue, decoder, thread


@pytest.fixture
def queue_decoding_ahead():
    queue, decoder, thread = decoding_ahead()
    yield queue, decoder
    queue.stop()
    decoder.gate.set()
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


def test_the_next_image_is_decoded_ahead_while_the_worker_works_and_not_decoded_again(queue_decoding_ahead):
    queue, decoder = queue_decoding_ahead
    queue.put("compressed", "a", 0.0)
    first = queue.take()  # nothing waits behind it: nothing is decoded ahead yet
    queue.put("compressed", "b", 1.0)
    assert wait_until(lambda: decoder.calls == ["b"]), decoder.calls  # decoded while the worker holds "a"
    assert first.pixels() == "pixels of a"
    second = queue.take()
    assert second.state == DECODING and second.pixels() == "pixels of b"
    assert decoder.calls == ["b", "a"]  # b once, by the decode-ahead thread


def test_with_two_waiting_one_is_decoded_ahead_per_image_taken_oldest_first():
    queue, decoder, thread = decoding_ahead(capacity=2)
    try:
        queue.put("compressed", "a", 0.0)
        queue.take()
        queue.put("compressed", "b", 0.0)
        queue.put("compressed", "c", 0.0)
        assert wait_until(lambda: decoder.calls == ["b"])
        assert queue.take().pixels() == "pixels of b"  # the one decoded ahead: the oldest, taken next
        assert wait_until(lambda: decoder.calls == ["b", "c"])  # taking b allowed one more
        assert queue.take().pixels() == "pixels of c" and decoder.calls == ["b", "c"]
    finally:
        queue.stop()
        thread.join(5.0)


def test_at_most_one_image_is_decoded_ahead_per_image_taken(queue_decoding_ahead):
    queue, decoder = queue_decoding_ahead
    put_after_a_take(queue, decoder, "b")
    for message in ("c", "d"):  # a camera faster than the detector: each replaces the one before
        queue.put("compressed", message, 0.0)
    time.sleep(0.1)  # time for a wrong second decode ahead to show
    assert decoder.calls == ["b"]  # c and d wait undecoded; the worker decodes the one it takes
    image = queue.take()
    assert image.message == "d" and image.state == TAKEN and image.pixels() == "pixels of d"
    assert decoder.calls == ["b", "d"]


def test_the_worker_waits_for_a_decode_under_way_instead_of_decoding_twice(queue_decoding_ahead):
    queue, decoder = queue_decoding_ahead
    put_after_a_take(queue, decoder, "b", hold=True)
    image = queue.take()
    assert image.state == DECODING
    result = []
    worker = threading.Thread(target=lambda: result.append(image.pixels()))
    worker.start()
    worker.join(0.1)
    assert worker.is_alive() and result == []  # still decoding
    decoder.gate.set()
    worker.join(5.0)
    assert result == ["pixels of b"] and decoder.calls == ["b"]


def test_a_decode_error_ahead_reaches_the_worker_as_if_it_had_decoded_the_image(queue_decoding_ahead):
    queue, decoder = queue_decoding_ahead
    put_after_a_take(queue, decoder, "bad")
    image = queue.take()
    with pytest.raises(ValueError, match="bad bytes"):
        image.pixels()
    assert decoder.calls == ["bad"]  # raised from the decode done ahead, not from a second one


def test_stop_during_a_decode_ahead_still_hands_the_worker_its_image_and_ends_the_thread():
    queue, decoder, thread = decoding_ahead()
    put_after_a_take(queue, decoder, "b", hold=True)
    image = queue.take()
    assert queue.stop() == 0
    decoder.gate.set()
    assert image.pixels() == "pixels of b"
    thread.join(5.0)
    assert not thread.is_alive()


def test_stop_wakes_a_waiting_take_drops_what_waits_and_refuses_new_images():
    queue = ImageQueue(2, Decoder())
    taken = []
    worker = threading.Thread(target=lambda: taken.append(queue.take()))
    worker.start()
    time.sleep(0.05)
    started = time.monotonic()
    assert queue.stop() == 0
    worker.join(5.0)
    assert taken == [None] and time.monotonic() - started < 0.4  # woken, not found by the 0.5 s re-check
    stopped = ImageQueue(2, Decoder())
    stopped.put("raw", "a", 0.0)
    stopped.put("raw", "b", 0.0)
    assert stopped.stop() == 2  # counted as dropped by the node
    assert stopped.put("raw", "c", 0.0) == 1 and stopped.take() is None


def test_a_queue_holds_at_least_one_image():
    with pytest.raises(ValueError, match="at least one image"):
        ImageQueue(0, Decoder())
