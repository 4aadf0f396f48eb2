"""The own ship's samples of a dataset folder (``own_ship.csv``) as bag messages for one video's window.

A camera on a ship needs the ship's attitude and position at every image's stamp; a replayed bag therefore carries
them beside the images, as a ship's own drivers would publish them: ``sensor_msgs/NavSatFix`` on
``/own_ship/fix`` and a REP-103 ``sensor_msgs/Imu`` (frame ``base_link``) on ``/own_ship/imu``, each stamped with
the sample's time. Holes in the samples are counted, since the runtime refuses an attitude inside one.

They are logged ``LEAD_S`` ahead of their stamps: live, a sensor's sample reaches the detector before the image of
the same instant does (the image is encoded, sent and decoded first), so the detector interpolates the attitude at
the image's stamp between the samples either side. A replay that sends each image and waits for its detections
(``./vessel demo``) would otherwise hold back the sample after the image until the image is done.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from vessel_calib.own_ship import DEFAULT_MAX_AGE_S, OwnShipSample, gaps
from vessel_common.errors import DataError
from vessel_detect import bag_messages, bag_topics
from vessel_tools.detect.bag_merge import TimedMessage

OWN_SHIP_FRAME_ID = "base_link"
LEAD_S = 0.5
LEAD_NS = int(LEAD_S * 1e9)
MAX_GAP_S = 2.0 * DEFAULT_MAX_AGE_S
"""A step between samples the runtime buffer would not interpolate across (its default): counted as a gap."""


@dataclass
class OwnShipWindow:
    """The own-ship messages of one bag, in stamp order, and what they hold."""

    messages: list[TimedMessage] = field(default_factory=list)
    fixes: int = 0
    attitudes: int = 0
    gaps: int = 0


def own_ship_window(samples: Sequence[OwnShipSample], first_s: float, last_s: float, options) -> OwnShipWindow:
    """The fix (NO_FIX without a position) and the Imu (with an attitude) of every sample in the window ± margin.

    ``options`` has ``own_ship_fix_topic``, ``own_ship_imu_topic``, ``own_ship_frame_id`` and
    ``own_ship_margin_s`` (``bag_build.BuildOptions``).
    """
    lo, hi = first_s - options.own_ship_margin_s, last_s + options.own_ship_margin_s
    inside = [s for s in samples if lo <= s.stamp <= hi]
    window = OwnShipWindow(gaps=len(gaps(inside, MAX_GAP_S)))
    for sample in inside:
        stamp_ns = bag_messages.sec_to_ns(sample.stamp)
        if sample.has_position:
            fix = bag_messages.nav_sat_fix(stamp_ns, sample.lat, sample.lon, frame_id=options.own_ship_frame_id)
        else:
            fix = bag_messages.nav_sat_fix(stamp_ns, math.nan, math.nan, frame_id=options.own_ship_frame_id,
                                           status=bag_topics.STATUS_NO_FIX)
        window.messages.append(TimedMessage(stamp_ns - LEAD_NS, options.own_ship_fix_topic, bag_topics.NAV_SAT_FIX,
                                            fix))
        window.fixes += 1
        if sample.attitude is not None:
            imu = bag_messages.imu(stamp_ns, sample.attitude, frame_id=options.own_ship_frame_id)
            window.messages.append(TimedMessage(stamp_ns - LEAD_NS, options.own_ship_imu_topic, bag_topics.IMU, imu))
            window.attitudes += 1
    return window


def add_arguments(group: argparse._ArgumentGroup) -> None:
    """The command-line options of the own-ship topics."""
    group.add_argument("--own-ship-fix-topic", default=bag_topics.DEFAULT_OWN_SHIP_FIX_TOPIC,
                       help="own ship's position (NavSatFix), from the dataset's own_ship.csv")
    group.add_argument("--own-ship-imu-topic", default=bag_topics.DEFAULT_OWN_SHIP_IMU_TOPIC,
                       help="own ship's attitude (Imu, REP-103), from the dataset's own_ship.csv")
    group.add_argument("--own-ship-frame-id", default=OWN_SHIP_FRAME_ID, help="frame_id of both (base_link)")
    group.add_argument("--own-ship-margin-s", type=float, default=5.0,
                       help="own-ship samples kept around the video (5 s)")


def options_of(args: argparse.Namespace) -> dict:
    """The ``BuildOptions`` fields of the own-ship options; ``DataError`` for a bad one."""
    if not (math.isfinite(args.own_ship_margin_s) and args.own_ship_margin_s >= 0):
        raise DataError(f"--own-ship-margin-s {args.own_ship_margin_s!r} must be a non-negative number")
    for flag, topic in (("--own-ship-fix-topic", args.own_ship_fix_topic),
                        ("--own-ship-imu-topic", args.own_ship_imu_topic)):
        if not topic.startswith("/") or " " in topic:
            raise DataError(f"{flag} {topic!r} is not an absolute topic name (e.g. /own_ship/imu)")
    return {"own_ship_fix_topic": args.own_ship_fix_topic, "own_ship_imu_topic": args.own_ship_imu_topic,
            "own_ship_frame_id": args.own_ship_frame_id, "own_ship_margin_s": args.own_ship_margin_s}
