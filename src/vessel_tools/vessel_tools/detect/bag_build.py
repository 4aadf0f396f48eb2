"""Build rosbag2 MCAP bags from the challenge data or from a video file with a GPS track.

Dataset mode (`--data DIR`, a folder laid out like ../shared/aitas) writes one bag per video, `BAGDIR/video_<N>`,
with the frame JPEGs exactly as they are on `/camera/image_raw/compressed` (stamp = the frame's UTC), the camera
position on `/camera/fix` (at the first frame, then at `--camera-fix-rate`) and every GPS fix of the vessel within
the video's time window (plus a margin) on `/vessel/gps_truth`; when the folder has an `own_ship.csv` (a camera on
a ship), its samples within the window (plus a margin) on `/own_ship/fix` (NavSatFix) and `/own_ship/imu` (Imu,
REP-103, frame `base_link`). Video mode (`--video FILE`) re-encodes the frames
of any video OpenCV reads as JPEG, stamped from `--start-utc` plus the video's own frame times, with the GPS of a
CSV or GPX track. Message log times equal header stamps. A bag is written beside its final place and renamed
when complete, so an interrupted build leaves no half bag.

    bag_build --data ../shared/aitas --videos 13-17 --out bags
    bag_build --video boat.mp4 --start-utc 2024-05-01T10:00:00Z --gps boat.gpx \
        --camera-lat 32.70297 --camera-lon -117.234631 --out bags
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from vessel_calib.gps_track import GpsTrack
from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError
from vessel_common.paths import default_data_dir, parse_videos, repo_root
from vessel_detect import bag_messages, bag_reader, bag_salvage, bag_topics, bag_writer
from vessel_detect.file_sources import VideoSource, parse_utc
from vessel_detect.image_source import jpeg_problem
from vessel_tools.calib.dataset import Dataset
from vessel_tools.detect import own_ship_bag
from vessel_tools.detect.bag_merge import MessageMerger, TimedMessage

_NS_PER_S = 1_000_000_000
MAX_LISTED_PROBLEMS = 10


@dataclass
class BuildOptions:
    """Topic names, frames and rates of the bags (defaults: the project's topics)."""

    image_topic: str = bag_topics.DEFAULT_IMAGE_TOPIC
    camera_fix_topic: str = bag_topics.DEFAULT_CAMERA_FIX_TOPIC
    gps_truth_topic: str = bag_topics.DEFAULT_GPS_TRUTH_TOPIC
    own_ship_fix_topic: str = bag_topics.DEFAULT_OWN_SHIP_FIX_TOPIC
    own_ship_imu_topic: str = bag_topics.DEFAULT_OWN_SHIP_IMU_TOPIC
    own_ship_frame_id: str = own_ship_bag.OWN_SHIP_FRAME_ID
    own_ship_margin_s: float = 5.0
    camera_frame_id: str = "camera"
    gps_frame_id: str = "vessel_gps"
    camera_fix_rate_hz: float = 1.0  # 0: only one fix, at the first frame
    camera_sigma_m: float | None = None  # None: covariance unknown
    camera_alt_m: float = math.nan
    gps_margin_s: float = 5.0
    jpeg_quality: int = 95
    overwrite: bool = False


@dataclass
class BuildResult:
    """What one bag holds and what was skipped building it."""

    name: str
    path: Path
    frames: int = 0
    skipped_frames: int = 0
    camera_fixes: int = 0
    gps_fixes: int = 0
    gps_skipped_rows: int = 0
    own_ship_fixes: int = 0
    own_ship_attitudes: int = 0
    own_ship_gaps: int = 0
    size_bytes: int = 0
    seconds: float = 0.0
    start_s: float = math.nan
    end_s: float = math.nan
    problems: list[str] = field(default_factory=list)

    def line(self) -> str:
        """One line for the progress display."""
        skipped = f", {self.skipped_frames} frames skipped" if self.skipped_frames else ""
        gps_bad = f", {self.gps_skipped_rows} GPS rows skipped" if self.gps_skipped_rows else ""
        own = (f", {self.own_ship_fixes} own-ship fixes and {self.own_ship_attitudes} attitudes"
               + (f" ({self.own_ship_gaps} gaps over {own_ship_bag.MAX_GAP_S:g} s)" if self.own_ship_gaps else "")
               if self.own_ship_fixes else "")
        return (
            f"{self.name}: {self.frames} frames{skipped}, {self.camera_fixes} camera fixes, {self.gps_fixes} GPS "
            f"fixes{gps_bad}{own}, {self.duration_s:.1f} s of data, {self.size_bytes / 1e6:.1f} MB in "
            f"{self.seconds:.2f} s"
        )

    @property
    def duration_s(self) -> float:
        """Time from the first to the last frame."""
        return self.end_s - self.start_s if math.isfinite(self.start_s) else 0.0


@dataclass(frozen=True)
class FrameInput:
    """A frame to write: stamp and a way to get its JPEG bytes (None with a reason if it cannot be read)."""

    stamp_ns: int
    label: str
    load: Callable[[], tuple[bytes | None, str | None]]


def folder_size(path: Path) -> int:
    """Bytes of every file under `path`."""
    return sum(p.stat().st_size for p in Path(path).rglob("*") if p.is_file())


def _check_time_order(previous: FrameInput | None, frame: FrameInput) -> None:
    if previous is not None and frame.stamp_ns <= previous.stamp_ns:
        raise DataError(
            f"frames out of time order: {frame.label} at {frame.stamp_ns / 1e9:.3f} s is not after "
            f"{previous.label} at {previous.stamp_ns / 1e9:.3f} s; fix the frame times (frames.csv utc, "
            "or --start-utc/--fps) and build again"
        )


def write_bag(
    path: Path,
    frames: Iterable[FrameInput],
    *,
    camera_lat: float,
    camera_lon: float,
    gps: tuple[list[int], list[float], list[float]] | None,
    options: BuildOptions,
    name: str,
    custom_data: dict[str, str] | None = None,
    on_frame: Callable[[int], None] | None = None,
    extra: Sequence[TimedMessage] = (),
) -> BuildResult:
    """Write one bag: frames (in increasing stamp order) merged in time with the camera and GPS fixes.

    Camera fixes are written at the first frame and then at the configured rate until the last frame. Of the
    GPS fixes (stamps ns, lats, lons; sorted), those within the margin around the first and last frame written;
    every ``extra`` message (sorted by stamp; their topics reliable) is written in time order with the rest.
    `DataError` for frames out of time order.
    """
    started = time.monotonic()
    result = BuildResult(name=name, path=path)
    bag_messages.validate_position(camera_lat, camera_lon, "camera position")
    margin_ns = round(options.gps_margin_s * _NS_PER_S)
    with bag_writer.BagWriter(path, overwrite=options.overwrite) as writer:
        for key, value in (custom_data or {}).items():
            writer.set_custom_data(key, value)
        writer.add_topic(options.image_topic, bag_topics.COMPRESSED_IMAGE, "sensor_data")
        writer.add_topic(options.camera_fix_topic, bag_topics.NAV_SAT_FIX, "latched")
        if gps is not None:
            writer.add_topic(options.gps_truth_topic, bag_topics.NAV_SAT_FIX, "reliable")
        for item in extra:
            writer.add_topic(item.topic, item.msgtype, "reliable")
        merger = MessageMerger(writer, result, options, (camera_lat, camera_lon), gps, margin_ns, extra)
        previous: FrameInput | None = None
        for frame in frames:
            _check_time_order(previous, frame)
            previous = frame
            data, reason = frame.load()
            if data is None:
                result.skipped_frames += 1
                result.problems.append(f"{frame.label}: {reason}; skipped")
                continue
            merger.frame(frame.stamp_ns, data)
            if on_frame is not None:
                on_frame(result.frames)
        if result.frames == 0:
            raise DataError(f"{name}: no readable frame to write (skipped {result.skipped_frames})")
        merger.finish()
    result.size_bytes = folder_size(path)
    result.seconds = time.monotonic() - started
    return result


def track_fixes(track) -> tuple[list[int], list[float], list[float]]:
    """A `GpsTrack`'s fixes as (stamps ns, lats, lons) lists."""
    return (
        [bag_messages.sec_to_ns(float(t)) for t in track.stamps],
        [float(v) for v in track.lats],
        [float(v) for v in track.lons],
    )


# ---------------------------------------------------------------------------------------------------------------
# Dataset mode
# ---------------------------------------------------------------------------------------------------------------
def _load_jpeg(path: Path) -> Callable[[], tuple[bytes | None, str | None]]:
    def load() -> tuple[bytes | None, str | None]:
        if not path.is_file():
            return None, f"{path} is missing"
        try:
            data = path.read_bytes()
        except OSError as exc:
            return None, f"cannot read {path} ({exc.strerror or exc})"
        reason = jpeg_problem(data, strict=True)
        if reason is not None:
            return None, f"{path} is unreadable ({reason})"
        return data, None

    return load


def build_from_dataset(
    data_dir: Path,
    out_dir: Path,
    videos: list[int] | None = None,
    options: BuildOptions | None = None,
    report: Callable[[str], None] | None = None,
) -> list[BuildResult]:
    """One bag per video of a dataset folder, `out_dir/video_<N>`; returns what each holds."""
    options = options or BuildOptions()
    dataset = Dataset(data_dir)
    wanted = dataset.check_videos(videos)
    if not options.overwrite:
        existing = [out_dir / f"video_{v}" for v in wanted if (out_dir / f"video_{v}").exists()]
        if existing:
            raise DataError(
                f"{', '.join(map(str, existing))} exist(s) already: pass --overwrite to replace, or choose --out"
            )
    track = dataset.gps_track()
    gps = track_fixes(track) if (dataset.path / "target_gps_fixes.csv").is_file() else None
    if report is not None and track.skipped_rows:
        report(f"  warning: {track.skipped_rows} rows of target_gps_fixes.csv have no position (NaN/empty); skipped")
    own_ship = dataset.own_ship()
    results = []
    for video in wanted:
        records = dataset.frames([video])
        frames = [
            FrameInput(bag_messages.sec_to_ns(r.stamp), f"video {video} frame {r.frame}", _load_jpeg(r.path))
            for r in records
        ]
        window = own_ship_bag.own_ship_window(own_ship or [], records[0].stamp, records[-1].stamp, options)
        if own_ship is not None and report is not None and not window.fixes:
            report(f"  warning: own_ship.csv has no sample within video {video}'s window; no own-ship topics")
        result = write_bag(
            out_dir / f"video_{video}",
            frames,
            camera_lat=dataset.camera_lat,
            camera_lon=dataset.camera_lon,
            gps=gps,
            options=options,
            name=f"video_{video}",
            custom_data={
                "vessel_detect.source": str(dataset.path.resolve()),
                "vessel_detect.video": str(video),
                "vessel_detect.builder": "vessel_detect bag_build",
            },
            extra=window.messages,
        )
        result.own_ship_fixes, result.own_ship_attitudes, result.own_ship_gaps = (
            window.fixes, window.attitudes, window.gaps)
        results.append(result)
        if report is not None:
            for problem in result.problems[:MAX_LISTED_PROBLEMS]:
                report(f"  warning: {problem}")
            if len(result.problems) > MAX_LISTED_PROBLEMS:
                report(f"  warning: ... and {len(result.problems) - MAX_LISTED_PROBLEMS} more frames skipped")
            report(result.line())
    return results


# ---------------------------------------------------------------------------------------------------------------
# Video mode
# ---------------------------------------------------------------------------------------------------------------
def _gps_track_file(gps_path: Path, start_utc: float) -> GpsTrack:
    """The vessel's track from a CSV or GPX file, or a ``DataError`` when it is missing or has no fix."""
    if not gps_path.is_file():
        raise DataError(f"GPS file {gps_path} does not exist")
    track = GpsTrack.from_file(gps_path, day_start=math.floor(start_utc / 86400.0) * 86400.0)
    if len(track) == 0:
        raise DataError(f"GPS file {gps_path} has no usable fix ({track.skipped_rows} rows skipped as NaN/garbage)")
    return track


def _warn_if_apart(track: GpsTrack, gps_path, start_utc: float, duration: float, margin_s: float,
                   report: Callable[[str], None]) -> None:
    """A warning line when the GPS track and the video's time span do not overlap (a wrong --start-utc)."""
    t0, t1 = track.time_span()
    if t1 < start_utc - margin_s or t0 > start_utc + duration + margin_s:
        report(
            f"  warning: the GPS track of {gps_path} ({t0:.0f}..{t1:.0f} s) does not overlap the video "
            f"({start_utc:.0f}..{start_utc + duration:.0f} s): check --start-utc"
        )


def _video_frames(source, video_name: str, max_frames: int | None, jpeg_quality: int) -> Iterator[FrameInput]:
    """The video's frames re-encoded as JPEG, at most ``max_frames``."""
    for count, frame in enumerate(source):
        if max_frames is not None and count >= max_frames:
            return
        jpeg = frame.jpeg_bytes(jpeg_quality)
        yield FrameInput(frame.stamp_ns, f"{video_name} frame {frame.index}", lambda data=jpeg: (data, None))


def build_from_video(
    video_path: Path,
    out_dir: Path,
    *,
    start_utc: float,
    camera_lat: float,
    camera_lon: float,
    gps_path: Path | None = None,
    name: str | None = None,
    fps: float | None = None,
    every: int = 1,
    max_frames: int | None = None,
    options: BuildOptions | None = None,
    report: Callable[[str], None] | None = None,
    counter: Callable[[int, int | None], None] | None = None,
) -> BuildResult:
    """One bag from a video file (frames re-encoded as JPEG) and, optionally, a GPS track file (CSV or GPX)."""
    options = options or BuildOptions()
    name = name or video_path.stem
    problems: list[str] = []
    source = VideoSource(video_path, start_utc=start_utc, fps=fps, every=every,
                         on_problem=lambda kind, message: problems.append(message))
    total = source.frame_count()
    if max_frames is not None and total is not None:
        total = min(total, max_frames)
    track = None
    if gps_path is not None:
        gps_path = Path(gps_path)
        track = _gps_track_file(gps_path, start_utc)
    gps = track_fixes(track) if track is not None else None
    if track is not None and report is not None:
        duration = (total * every / (fps or source.container_fps or 25.0)) if total else 0.0
        _warn_if_apart(track, gps_path, start_utc, duration, options.gps_margin_s, report)
    try:
        result = write_bag(
            out_dir / name,
            _video_frames(source, video_path.name, max_frames, options.jpeg_quality),
            camera_lat=camera_lat,
            camera_lon=camera_lon,
            gps=gps,
            options=options,
            name=name,
            custom_data={"vessel_detect.source": str(video_path.resolve()),
                         "vessel_detect.builder": "vessel_detect bag_build"},
            on_frame=(lambda n: counter(n, total)) if counter is not None else None,
        )
    finally:
        source.close()
    result.problems = problems + result.problems
    result.skipped_frames += source.stats.unreadable
    result.gps_skipped_rows = track.skipped_rows if track is not None else 0
    if report is not None:
        for problem in result.problems[:MAX_LISTED_PROBLEMS]:
            report(f"  warning: {problem}")
        report(result.line())
    return result


# ---------------------------------------------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------------------------------------------
def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bag_build",
        description="Build rosbag2 MCAP bags (one per video) from a dataset folder or from a video file.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=(
            "examples:\n"
            "  bag_build --data ../shared/aitas --videos 13-17 --out bags\n"
            "  bag_build --video boat.mp4 --start-utc 2024-05-01T10:00:00Z --gps track.gpx \\\n"
            "      --camera-lat 32.70297 --camera-lon -117.234631 --out bags\n"
            "  bag_build --info bags/video_13\n"
            "  bag_build --recover recording/video_13   # a recorder killed with -9"
        ),
    )
    mode = parser.add_argument_group("input (one of)")
    mode.add_argument("--data", type=Path, help="dataset folder like ../shared/aitas (default: $VESSEL_DATA)")
    mode.add_argument("--video", type=Path, help="a video file OpenCV reads (mp4, avi, mkv, ...)")
    mode.add_argument("--info", type=Path, nargs="+", metavar="BAG", help="print what bags hold and exit")
    mode.add_argument("--recover", type=Path, metavar="BAG",
                      help="make a bag whose writer died (or that was cut short) readable: every message up to "
                      "where it breaks, less any chunk whose checksum fails, rewritten with its index and "
                      "metadata.yaml (in place, keeping the damaged file as BAG.damaged[.N].mcap; or to --out)")
    parser.add_argument("--videos", help="dataset videos, e.g. 13,14 or 7-12 (default: all)")
    parser.add_argument("--out", type=Path, help="folder for the bags (default: <repo>/bags)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace bags (or a --recover --out) that exist already")

    video = parser.add_argument_group("video mode")
    video.add_argument("--start-utc", help="UTC time of the video's first frame (ISO-8601 or epoch seconds)")
    video.add_argument("--gps", type=Path, help="GPS track of the vessel (CSV with lat, lon, time; or GPX)")
    video.add_argument("--camera-lat", type=float, help="camera latitude, degrees")
    video.add_argument("--camera-lon", type=float, help="camera longitude, degrees")
    video.add_argument("--fps", type=float, help="frame rate to stamp with (default: the video's own frame times)")
    video.add_argument("--every", type=int, default=1, help="keep one frame in N (default 1)")
    video.add_argument("--max-frames", type=int, help="stop after this many frames")
    video.add_argument("--name", help="bag folder name (default: the video file's stem)")
    video.add_argument("--jpeg-quality", type=int, default=95, help="JPEG quality of re-encoded frames (95)")

    topics = parser.add_argument_group("topics and messages")
    topics.add_argument("--image-topic", default=bag_topics.DEFAULT_IMAGE_TOPIC)
    topics.add_argument("--camera-fix-topic", default=bag_topics.DEFAULT_CAMERA_FIX_TOPIC)
    topics.add_argument("--gps-truth-topic", default=bag_topics.DEFAULT_GPS_TRUTH_TOPIC)
    topics.add_argument("--frame-id", default="camera", help="frame_id of images and the camera fix")
    topics.add_argument("--gps-frame-id", default="vessel_gps", help="frame_id of the vessel's GPS fixes")
    topics.add_argument("--camera-fix-rate", type=float, default=1.0, help="camera fixes per second (0: one)")
    topics.add_argument("--camera-sigma-m", type=float, help="1-sigma camera position error, m (default unknown)")
    topics.add_argument("--camera-alt", type=float, default=math.nan, help="camera altitude, m (default unknown)")
    topics.add_argument("--gps-margin-s", type=float, default=5.0, help="GPS fixes kept around the video (5 s)")
    own_ship_bag.add_arguments(topics)
    return parser


def _options(args: argparse.Namespace) -> BuildOptions:
    for flag, value in (("--camera-fix-rate", args.camera_fix_rate), ("--gps-margin-s", args.gps_margin_s)):
        if not (math.isfinite(value) and value >= 0):
            raise DataError(f"{flag} {value!r} must be a non-negative number")
    if not 1 <= args.jpeg_quality <= 100:
        raise DataError(f"--jpeg-quality {args.jpeg_quality} must be within 1..100")
    for flag, topic in (
        ("--image-topic", args.image_topic),
        ("--camera-fix-topic", args.camera_fix_topic),
        ("--gps-truth-topic", args.gps_truth_topic),
    ):
        if not topic.startswith("/") or " " in topic:
            raise DataError(f"{flag} {topic!r} is not an absolute topic name (e.g. /camera/image_raw/compressed)")
    return BuildOptions(
        image_topic=args.image_topic,
        camera_fix_topic=args.camera_fix_topic,
        gps_truth_topic=args.gps_truth_topic,
        camera_frame_id=args.frame_id,
        gps_frame_id=args.gps_frame_id,
        camera_fix_rate_hz=args.camera_fix_rate,
        camera_sigma_m=args.camera_sigma_m,
        camera_alt_m=args.camera_alt,
        gps_margin_s=args.gps_margin_s,
        jpeg_quality=args.jpeg_quality,
        overwrite=args.overwrite,
        **own_ship_bag.options_of(args),
    )


def _default_out() -> Path:

    return repo_root() / "bags"


class _Counter:
    """A frame counter rewritten in place on a terminal, a line every 10 % otherwise."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.tty = sys.stderr.isatty()
        self.last_decile = -1

    def __call__(self, done: int, total: int | None) -> None:
        if self.tty:
            if done % 10 == 0 or done == total:
                of = f"/{total}" if total else ""
                print(f"\r  {self.name}: frame {done}{of}", end="", file=sys.stderr, flush=True)
        elif total:
            decile = 10 * done // total
            if decile > self.last_decile:
                self.last_decile = decile
                print(f"  {self.name}: {10 * decile} % ({done}/{total} frames)", file=sys.stderr, flush=True)

    def end(self) -> None:
        if self.tty:
            print(file=sys.stderr)


def _run_video(args: argparse.Namespace, out_dir: Path, options: BuildOptions, say: Callable[[str], None]
               ) -> BuildResult:
    """Video mode of ``run``: check its options and build the one bag."""
    missing = [f for f, v in (("--start-utc", args.start_utc), ("--camera-lat", args.camera_lat),
                              ("--camera-lon", args.camera_lon)) if v is None]
    if missing:
        raise DataError(f"video mode needs {', '.join(missing)} (the frames' UTC and the camera position)")
    if not args.video.is_file():
        raise DataError(f"video file {args.video} does not exist: check the path")
    if args.every < 1:
        raise DataError(f"--every {args.every} must be at least 1")
    name = args.name or args.video.stem
    say(f"building {out_dir / name} from {args.video}")
    counter = _Counter(name)
    try:
        result = build_from_video(
            args.video,
            out_dir,
            start_utc=parse_utc(args.start_utc),
            camera_lat=args.camera_lat,
            camera_lon=args.camera_lon,
            gps_path=args.gps,
            name=name,
            fps=args.fps,
            every=args.every,
            max_frames=args.max_frames,
            options=options,
            report=lambda line: (counter.end(), say(line)),
            counter=counter,
        )
    finally:
        counter.end()
    return result


def run(argv: list[str] | None = None) -> int:
    """Parse arguments and build; raises VesselError on bad input."""
    args = _parser().parse_args(argv)

    def say(line: str) -> None:
        print(line, flush=True)

    if args.info:
        for path in args.info:
            print(bag_reader.bag_info(path))
        return 0
    if args.recover:
        salvage = bag_salvage.recover_bag(args.recover, args.out, overwrite=args.overwrite)
        print(f"recovered {args.out or args.recover}: {salvage.describe()}")
        return 0 if salvage.complete else 1  # 1: messages were lost (cut short, or damaged chunks left out)
    if args.data is not None and args.video is not None:
        raise DataError("give either --data (a dataset folder) or --video (a video file), not both")
    options = _options(args)
    out_dir = args.out if args.out is not None else _default_out()
    started = time.monotonic()
    if args.video is not None:
        results = [_run_video(args, out_dir, options, say)]
    else:
        data_dir = args.data if args.data is not None else default_data_dir()
        if data_dir is None:
            raise DataError("no dataset folder: pass --data DIR or set VESSEL_DATA (or give --video FILE)")
        videos = parse_videos(args.videos) if args.videos else None
        say(f"building bags in {out_dir} from {data_dir}")
        results = build_from_dataset(data_dir, out_dir, videos, options, report=say)
    total_bytes = sum(r.size_bytes for r in results)
    say(
        f"done: {len(results)} bag(s), {sum(r.frames for r in results)} frames "
        f"({sum(r.skipped_frames for r in results)} skipped), {sum(r.camera_fixes for r in results)} camera fixes, "
        f"{sum(r.gps_fixes for r in results)} GPS fixes, {total_bytes / 1e6:.1f} MB in "
        f"{time.monotonic() - started:.1f} s -> {out_dir}"
    )
    return 0


@command_line_tool(interrupted='interrupted: no partial bag was left behind')
def main(argv: list[str] | None = None) -> int:
    """Console entry point: exit 0 on success, 2 with one `error:` line on bad input."""
    return run(argv)


if __name__ == "__main__":
    sys.exit(main())
