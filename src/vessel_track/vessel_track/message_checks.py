"""What the tracker, fuser and gps_publisher refuse: checks of every input field they read (ROS-free).

The nodes call these at their subscription boundary, before anything reaches the tracker or fuser core, and report
each refusal on ``/diagnostics`` through ``NodeHealth.problem(kind, message)``: logged once per kind, counted every
time, and the refused message or element is not passed on. The functions take the message objects' fields (a
``builtin_interfaces/Time`` is anything with ``sec`` and ``nanosec``; a track anything with ``VesselTrack``'s
fields), so they are tested without ROS (``test_message_checks.py``).

What is dropped, and why at that level:

* **The whole message** when its header stamp is invalid (``bad_stamp``: nanosec >= 1e9, zero or negative), equal
  to the previous one's (``duplicate_stamp``) or slightly older (``out_of_order_frames``). The header stamp is the
  time of every element and of every output: with a wrong one nothing in the message can be placed in time, and a
  second copy of a frame would update the filters twice and publish two fixes with one stamp. A step back of
  ``backwards_reset_s`` or more is not refused: it is a replay restarting, and the nodes reset (``resets``,
  ``stamp_backwards``).
* **One detection** with an impossible score (``bad_score``), and **one track** with an impossible field (the other
  kinds): each detection is a measurement of its own and each track a vessel of its own, so one corrupt element
  says nothing about the others, and dropping the whole frame would blind collision avoidance to every vessel in
  it. Every track sharing an id with another (``duplicate_track_id``) is dropped, since neither can be told to be
  the real one. A dropped element is counted once, under its first problem.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

NANOSEC_PER_SEC = 1_000_000_000
TIME_TOLERANCE_S = 1e-6
"""A time in a message may be this much after the header stamp: a float stamp rounded to the nanosecond and back."""
BACKWARDS_RESET_S = 1.0
"""A stamp this far or further before the previous one is a replay restarting (the tracker's default
``backwards_reset_s``); a smaller step back is an out-of-order message. The tracker uses its own parameter; the
tracker never publishes a smaller step back, so the fuser and gps_publisher see only restarts."""
TRACK_STATUSES = {0: "TENTATIVE", 1: "CONFIRMED", 2: "COASTING", 3: "LOST"}
"""The ``VesselTrack.STATUS_*`` constants."""

TRACK_ARRAY_TYPE = "vessel_msgs/msg/VesselTrackArray"
"""The tracking chain's array type, as ``vessel_common.wire`` names it."""
STATUS_LOST = 3

PROBLEMS = {
    "bad_stamp": "the whole message was dropped (every output would carry its stamp); fix the publisher's stamps",
    "duplicate_stamp": "the message was dropped (a second copy of a frame would update the filters twice)",
    "out_of_order_frames": "the message was dropped (stamped slightly before the previous one)",
    "bad_score": "the detection was dropped (scores are probabilities: finite, in [0, 1])",
    "duplicate_track_id": "every track with that id was dropped (neither can be told to be the real one)",
    "bad_track_status": "the track was dropped (status must be one of VesselTrack's STATUS_* constants)",
    "bad_confidence": "the track was dropped (confidence is a probability: finite, in [0, 1])",
    "bad_track_time": "the track was dropped (its header stamp must be the array's, first_seen <= last_seen <= "
                      "the stamp, all valid stamps)",
    "bad_screen_covariance": "the track was dropped (screen_covariance must be finite, symmetric, positive "
                             "semi-definite)",
    "bad_screen_velocity": "the track was dropped (screen_velocity must be finite)",
    "bad_covariance": "the track was dropped (a world covariance must be finite, symmetric and positive "
                      "semi-definite; all NaN only without has_world)",
    "bad_expected_error": "the track was dropped (expected_error_m must be finite and >= 0; NaN only without "
                          "has_world)",
}
"""Every kind these checks count, with what the node did about it (the log line's second half)."""


@dataclass(frozen=True)
class Refusal:
    """One refused message or element: the diagnostics counter (``kind``) and what was wrong with it."""

    kind: str
    detail: str

    @property
    def message(self) -> str:
        """The line ``NodeHealth.problem`` logs (once per kind)."""
        return f"{self.detail}: {PROBLEMS[self.kind]}"


def report(health, refusals) -> None:
    """Count each refusal on a node's ``NodeHealth`` (anything with ``problem(kind, message)``)."""
    for refusal in refusals:
        health.problem(refusal.kind, refusal.message)


def stamp_seconds(stamp) -> float:
    """Seconds of a ``builtin_interfaces/Time`` (as ``vessel_common.qos.stamp_to_sec``)."""
    return int(stamp.sec) + int(stamp.nanosec) * 1e-9


def stamp_problem(stamp, what: str = "header stamp") -> str:
    """Why ``stamp`` is not a valid time, or "": nanosec must be below 1e9 and the time after 0."""
    sec, nanosec = int(stamp.sec), int(stamp.nanosec)
    if not 0 <= nanosec < NANOSEC_PER_SEC:
        return f"{what} has nanosec {nanosec} (must be below 1e9)"
    if sec < 0 or (sec == 0 and nanosec == 0):
        return f"{what} is {sec + nanosec * 1e-9:g} s: zero or negative (unset?)"
    return ""


def header_refusal(stamp) -> Refusal | None:
    """``bad_stamp`` for an invalid header stamp, else None."""
    problem = stamp_problem(stamp)
    return Refusal("bad_stamp", problem) if problem else None


def stamp_order(stamp_s: float, previous_s: float | None, backwards_reset_s: float = BACKWARDS_RESET_S) -> str:
    """Where ``stamp_s`` falls against the previous accepted stamp.

    ``first``, ``newer``, ``duplicate``, ``out_of_order`` (back by less than ``backwards_reset_s``) or ``restart``
    (back by ``backwards_reset_s`` or more: a replay restarted).
    """
    if previous_s is None:
        return "first"
    if stamp_s > previous_s:
        return "newer"
    if stamp_s == previous_s:
        return "duplicate"
    return "out_of_order" if previous_s - stamp_s < backwards_reset_s else "restart"


def order_refusal(stamp_s: float, previous_s: float | None,
                  backwards_reset_s: float = BACKWARDS_RESET_S) -> Refusal | None:
    """``duplicate_stamp`` or ``out_of_order_frames`` for a stamp that is not after the previous one, else None.

    A restart (back by ``backwards_reset_s`` or more) is not refused: the caller resets.
    """
    order = stamp_order(stamp_s, previous_s, backwards_reset_s)
    if order == "duplicate":
        return Refusal("duplicate_stamp", f"a message stamped {stamp_s:.9f} s, as the previous one")
    if order == "out_of_order":
        return Refusal("out_of_order_frames", f"a message stamped {previous_s - stamp_s:.3g} s before the "
                                              "previous one")
    return None


def probability_problem(value, what: str) -> str:
    """Why ``value`` is not a probability (finite, in [0, 1]), or ""."""
    value = float(value)
    return "" if math.isfinite(value) and 0.0 <= value <= 1.0 else f"{what} {value:g} (must be finite, in [0, 1])"


def detection_refusal(detection) -> Refusal | None:
    """``bad_score`` for a ``Detection2D`` with any hypothesis score that is not a probability, else None."""
    for result in detection.results:
        problem = probability_problem(result.hypothesis.score, f"detection score of {result.hypothesis.class_id!r}:")
        if problem:
            return Refusal("bad_score", problem)
    return None


def checked_detections(detections: Sequence) -> tuple[list, list[Refusal]]:
    """The detections that pass ``detection_refusal`` and the refusals of the others."""
    kept, refusals = [], []
    for detection in detections:
        refusal = detection_refusal(detection)
        if refusal is None:
            kept.append(detection)
        else:
            refusals.append(refusal)
    return kept, refusals


def covariance_problem(values, what: str = "position covariance", unknown_allowed: bool = False) -> str:
    """Why a 2x2 covariance (4 values, row-major) is impossible, or "".

    It must be finite, symmetric and positive semi-definite, to the precision of its own entries; with
    ``unknown_allowed``, all NaN (unknown) passes too.
    """
    values = np.asarray(values, dtype=float).reshape(-1)
    if values.size != 4:
        return f"{what} has {values.size} values, not 4"
    a, b, c, d = (float(v) for v in values)
    finite = all(math.isfinite(v) for v in (a, b, c, d))
    if not finite and unknown_allowed and all(math.isnan(v) for v in (a, b, c, d)):
        return ""
    if not finite:
        return f"{what} is not finite"
    scale = max(abs(a), abs(b), abs(c), abs(d)) or 1.0
    if abs(b - c) > 1e-6 * scale:
        return f"{what} is not symmetric ({b:g} against {c:g})"
    off_diagonal = 0.5 * (b + c)
    least_eigenvalue = 0.5 * (a + d) - math.hypot(0.5 * (a - d), off_diagonal)
    if least_eigenvalue < -1e-9 * scale:
        return f"{what} is not positive semi-definite (diagonal {a:g}, {d:g})"
    return ""


def track_time_problem(track, stamp, previous_s: float | None = None) -> str:
    """Why a track's times do not fit the array stamped ``stamp`` (a Time), or "".

    The track's header stamp is the array's; first_seen and last_seen are valid stamps with first_seen <=
    last_seen <= the stamp (``TIME_TOLERANCE_S``). A LOST track may have been seen up to ``previous_s`` (the
    previous message's stamp): a tracker restarted by a replay reports its old tracks LOST at the earlier stamp.
    """
    for what, value in (("first_seen", track.first_seen), ("last_seen", track.last_seen)):
        problem = stamp_problem(value, what)
        if problem:
            return problem
    now = stamp_seconds(stamp)
    header = stamp_seconds(track.header.stamp)
    if abs(header - now) > TIME_TOLERANCE_S:
        return f"track header stamp {header:.9f} s is not the array's {now:.9f} s"
    first, last = stamp_seconds(track.first_seen), stamp_seconds(track.last_seen)
    limit = now if track.status != STATUS_LOST or previous_s is None else max(now, previous_s)
    if last > limit + TIME_TOLERANCE_S:
        return f"last_seen is {last - now:.6g} s after the message stamp"
    if first > last + TIME_TOLERANCE_S:
        return f"first_seen is {first - last:.6g} s after last_seen"
    return ""


def world_problem(track) -> Refusal | None:
    """The fuser's fields of a track: covariances and expected error, known whenever ``has_world`` is set."""
    unknown_allowed = not track.has_world
    for what in ("position_covariance", "velocity_covariance"):
        problem = covariance_problem(getattr(track, what), what, unknown_allowed)
        if problem:
            return Refusal("bad_covariance", problem)
    error = float(track.expected_error_m)
    if not ((math.isnan(error) and unknown_allowed) or (math.isfinite(error) and error >= 0.0)):
        return Refusal("bad_expected_error", f"expected_error_m {error:g}" + (" with has_world set" if
                                                                               math.isnan(error) else ""))
    return None


def track_refusal(track, stamp, previous_s: float | None = None, world: bool = False) -> Refusal | None:
    """The first problem of one ``VesselTrack`` in an array stamped ``stamp``, or None.

    Checked: status, confidence, times (``track_time_problem``), screen covariance and velocity, and with
    ``world`` (the fuser's output) the world covariances and expected error. The id is checked across the array
    by ``checked_tracks``.
    """
    if int(track.status) not in TRACK_STATUSES:
        return Refusal("bad_track_status", f"track {track.id!r} has status {int(track.status)}")
    problem = probability_problem(track.confidence, f"track {track.id!r} has confidence")
    if problem:
        return Refusal("bad_confidence", problem)
    problem = track_time_problem(track, stamp, previous_s)
    if problem:
        return Refusal("bad_track_time", f"track {track.id!r}: {problem}")
    problem = covariance_problem(track.screen_covariance, "screen_covariance")
    if problem:
        return Refusal("bad_screen_covariance", f"track {track.id!r}: {problem}")
    velocity = (float(track.screen_velocity.x), float(track.screen_velocity.y))
    if not all(math.isfinite(v) for v in velocity):
        return Refusal("bad_screen_velocity", f"track {track.id!r} has screen_velocity {velocity}")
    refusal = world_problem(track) if world else None
    return None if refusal is None else Refusal(refusal.kind, f"track {track.id!r}: {refusal.detail}")


def checked_tracks(tracks: Sequence, stamp, previous_s: float | None = None,
                   world: bool = False) -> tuple[list, list[Refusal]]:
    """The tracks of one array that pass every check, and the refusals of the others (one per dropped track).

    Ids must be unique within the array: every track of a repeated id is refused (``duplicate_track_id``).
    """
    ids = Counter(track.id for track in tracks)
    kept, refusals = [], []
    for track in tracks:
        if ids[track.id] > 1:
            refusal = Refusal("duplicate_track_id", f"{ids[track.id]} tracks with id {track.id!r} in one array")
        else:
            refusal = track_refusal(track, stamp, previous_s, world)
        if refusal is None:
            kept.append(track)
        else:
            refusals.append(refusal)
    return kept, refusals
