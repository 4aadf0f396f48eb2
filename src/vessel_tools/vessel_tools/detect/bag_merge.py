"""One bag's messages in time order: frames, the camera's fix, the vessel's GPS and other timed messages.

A replay publishes a bag's messages in log-time order, and a consumer that looks up the vessel's GPS or the own
ship's attitude at an image's stamp needs them before or with that image; so every message is written in stamp
order, with log time equal to its header stamp. ``bag_build`` feeds the frames; this merges the rest in.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

from vessel_detect import bag_messages

_NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class TimedMessage:
    """A message to write at log time ``stamp_ns`` on ``topic`` of type ``msgtype`` (a rosbags message object)."""

    stamp_ns: int
    topic: str
    msgtype: str
    message: object


def camera_fix_stamps(first_ns: int, rate_hz: float) -> Iterator[int]:
    """Stamps of the camera's fix: the first frame, then every 1/rate s (forever; the writer stops asking)."""
    yield first_ns
    if rate_hz <= 0:
        return
    period_ns = round(_NS_PER_S / rate_hz)
    k = 1
    while True:
        yield first_ns + k * period_ns
        k += 1


class MessageMerger:
    """Writes one bag's frames, camera fixes, GPS fixes and ``extra`` messages in time order, counting in ``result``.

    The GPS fixes (stamps ns, lats, lons; sorted) are kept within ``margin_ns`` of the first and last frame; the
    ``extra`` messages (sorted by stamp) are all written, the caller having chosen them for the bag's window.
    """

    def __init__(self, writer, result, options, camera_latlon: tuple[float, float],
                 gps: tuple[list[int], list[float], list[float]] | None, margin_ns: int,
                 extra: Sequence[TimedMessage] = ()) -> None:
        self.writer, self.result, self.options = writer, result, options
        self.camera_lat, self.camera_lon = camera_latlon
        self.gps_ns, self.gps_lat, self.gps_lon = gps if gps is not None else ([], [], [])
        self.margin_ns = margin_ns
        self.gps_index = 0
        self.extra, self.extra_index = list(extra), 0
        self.fix_stamps: Iterator[int] | None = None
        self.next_fix_ns: int | None = None

    def _write_gps(self) -> None:
        i = self.gps_index
        fix = bag_messages.nav_sat_fix(self.gps_ns[i], self.gps_lat[i], self.gps_lon[i],
                                       frame_id=self.options.gps_frame_id)
        self.writer.write(self.options.gps_truth_topic, fix)
        self.result.gps_fixes += 1
        self.gps_index += 1

    def _write_extra(self) -> None:
        item = self.extra[self.extra_index]
        self.writer.write(item.topic, item.message, item.stamp_ns)
        self.extra_index += 1

    def side_until(self, stamp_ns: int) -> None:
        """Every GPS fix and extra message not yet written stamped at or before ``stamp_ns``, in stamp order."""
        while True:
            gps_ns = self.gps_ns[self.gps_index] if self.gps_index < len(self.gps_ns) else None
            extra_ns = self.extra[self.extra_index].stamp_ns if self.extra_index < len(self.extra) else None
            if extra_ns is not None and extra_ns <= stamp_ns and (gps_ns is None or extra_ns < gps_ns):
                self._write_extra()
            elif gps_ns is not None and gps_ns <= stamp_ns:
                self._write_gps()
            else:
                return

    def frame(self, stamp_ns: int, data: bytes) -> None:
        """One readable frame, after the camera fixes, GPS fixes and extra messages due by its stamp."""
        options = self.options
        if self.fix_stamps is None:
            self.fix_stamps = camera_fix_stamps(stamp_ns, options.camera_fix_rate_hz)
            self.next_fix_ns = next(self.fix_stamps)
            self.result.start_s = stamp_ns / 1e9
            while self.gps_index < len(self.gps_ns) and self.gps_ns[self.gps_index] < stamp_ns - self.margin_ns:
                self.gps_index += 1  # before the video's window
        while self.next_fix_ns is not None and self.next_fix_ns <= stamp_ns:
            self.side_until(self.next_fix_ns)
            fix = bag_messages.nav_sat_fix(self.next_fix_ns, self.camera_lat, self.camera_lon, options.camera_alt_m,
                                           frame_id=options.camera_frame_id, sigma_m=options.camera_sigma_m)
            self.writer.write(options.camera_fix_topic, fix)
            self.result.camera_fixes += 1
            self.next_fix_ns = next(self.fix_stamps, None)
        self.side_until(stamp_ns)
        self.writer.write(options.image_topic,
                          bag_messages.compressed_image(stamp_ns, data, options.camera_frame_id, "jpeg"))
        self.result.frames += 1
        self.result.end_s = stamp_ns / 1e9

    def finish(self) -> None:
        """The GPS fixes up to the margin after the last frame, then the extra messages left."""
        self.side_until(bag_messages.sec_to_ns(self.result.end_s) + self.margin_ns)
        while self.extra_index < len(self.extra):
            self._write_extra()
