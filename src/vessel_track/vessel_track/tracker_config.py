"""The tracker's settings: every field with its unit, validated, and read from a parameter YAML.

``TrackerConfig`` holds them; ``load_tracker_config`` reads them from a parameter file as the tracker node declares
them.

``vessel_track.tracker`` explains the choices behind the defaults; ``vessel_track.association`` uses the
association fields.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from vessel_calib.params import node_blocks, read_params_yaml
from vessel_common.errors import CalibrationError, DataError

PROCESS_NOISE_MODELS = ("continuous_wna", "discrete_wna", "paper")
ASSOCIATION_METHODS = ("global", "greedy")
DISTANCE_METRICS = ("euclidean", "mahalanobis")


@dataclass
class TrackerConfig:
    """Every number of the tracker, with its unit. Defaults work on the challenge camera at 1280x720.

    Pixels are full-resolution screen pixels; times are seconds of the message stamps.
    """

    # --- Kalman filter ---
    measurement_std_px: float = 10.0
    """Standard deviation of a detection's box centre, px (the paper: R = 10² px² at half resolution)."""
    measurement_std_size_frac: float = 0.0
    """Extra centre noise proportional to the box size (fraction of w for x, of h for y): large, close boxes
    have looser centres. Added in quadrature to ``measurement_std_px``; 0 keeps the paper's constant R."""
    process_noise_model: str = "continuous_wna"
    """``continuous_wna`` (Q = q[[Δ³/3, Δ²/2], [Δ²/2, Δ]] per axis, consistent for any frame rate),
    ``discrete_wna`` (Q = q[[Δ⁴/4, Δ³/2], [Δ³/2, Δ²]]) or ``paper`` (Q = diag(0, qΔ², 0, qΔ²))."""
    process_noise: float = 30.0
    """q of the process noise model for x: px²/s³ (spectral density of the acceleration) for
    ``continuous_wna``, px²/s⁴ (acceleration variance) for ``discrete_wna`` and ``paper`` (the paper: 1 at
    half resolution, i.e. 4 at full resolution). 30 px²/s³ follows the U-turns of the challenge boat between
    labelled frames 4-7 s apart (velocity reversals of 50 px/s) without splitting its track."""
    process_noise_y: float = 0.25
    """q for y, same units as ``process_noise``. Near the horizon a vessel's screen motion is mostly
    horizontal, so a smaller value here keeps coasting tracks from drifting onto clutter below or above."""
    init_velocity_std_x_px_s: float = 30.0
    """Standard deviation of the unknown horizontal velocity of a new track, px/s (vessels in the challenge
    data move 5-50 px/s across the screen)."""
    init_velocity_std_y_px_s: float = 10.0
    """Standard deviation of the unknown vertical velocity of a new track, px/s (near the horizon vessels move
    little in y: a few px/s, up to ~20 px/s when passing close to the camera)."""

    # --- association ---
    association: str = "global"
    """``global``: one optimal assignment (Hungarian) of detections to tracks; ``greedy``: the paper's
    nearest-first matching (kept for comparison)."""
    distance_metric: str = "mahalanobis"
    """Association cost: ``mahalanobis`` (innovation d'S⁻¹d + ln det S, uses the predicted covariance) or
    ``euclidean`` ((distance / measurement_std_px)²)."""
    gate_px: float = 40.0
    """A detection within this distance of a predicted centre is always admissible, px (the paper: 80 px at
    half resolution)."""
    gate_sigmas: float = 4.0
    """Beyond ``gate_px``, a detection is admissible while its Mahalanobis distance to the prediction (with
    the predicted innovation covariance) is at most this: the gate grows along the directions where the
    prediction is uncertain, after a long coast or at the start of a track."""
    max_gate_px: float = 240.0
    """No detection farther than this from a predicted centre is admissible, px: bounds how far a coasting
    track can reach."""
    clutter_density_per_mpx: float = 2.0
    """Expected false (or new-vessel) detections per frame per million pixels. A detection is associated to a
    track only if it is more likely to come from the track than from clutter: the Gaussian likelihood of its
    centre (predicted innovation covariance S) and, with ``size_weight`` > 0, of its log box size
    (``size_log_std``), against clutter spread at this density with sizes spread over a decade. This keeps a
    track that has coasted for a long time (large S) from taking a stray box far from its prediction or of
    another size, while a confident track keeps its full ``gate_sigmas`` gate. In the global assignment the
    same likelihood is the cost of leaving a track without a detection, so a track is not given a worse box
    just so that another track gets a barely admissible one. 0 disables the test. 2.0: measured on the
    challenge detector's output with the vessel-of-interest cue on training videos 7-12 (0.8 boxes per frame
    that are not the vessel, in the 0.44 Mpx band below the horizon: 1.8 per Mpx)."""
    size_weight: float = 1.0
    """Weight of the box-size similarity term in the association cost (0 disables it)."""
    size_log_std: float = 0.4
    """Expected change of ln(box width) and ln(box height) between associated detections (0.4: about ±50 %;
    hand boxes of the challenge boat change by up to 2.3x between frames 4 s apart when it passes close)."""
    height_log_std: float = 0.2
    """Expected change of ln(box height) alone between detections close together in time (0: ``size_log_std``).
    A boat's width changes with its heading, its height almost only with its range, so the height can be held
    to a tighter model than the width: a track then does not move onto a box of another boat half its height."""
    height_log_std_rate: float = 0.0005
    """Growth of the height's expected change with time and nearness, per px of box height per s (0: constant).
    The height scales as 1/range, so ln(height) changes by (range rate / range) dt, and range is proportional to
    1/height: the expected change is ``height_log_std_rate x height x dt``, added in quadrature to
    ``height_log_std``, with the track's latest box height and the time since its latest box. A near boat may
    double its height between frames seconds apart, a far one barely changes, and frames milliseconds apart
    change by the detector's jitter alone."""
    max_size_ratio: float = 3.0
    """A detection whose width or height differs from the track's box by more than this factor is not
    associated (0 disables the size gate)."""
    confidence_weight: float = 2.0
    """Weight of the confidence-agreement term in the association cost (0 disables it). With confidences that
    are a probability of being one kind of vessel (the vessel of interest, ``confidence_class``), a track whose
    recent boxes were likely that vessel should not take a box the detector calls another boat, nor the other way
    round: the term is ``-2 ln(2 (q p + (1 - q)(1 - p)))``, q the mean of the track's last
    ``confidence_memory`` confidences and p the box's, both bounded to [0.05, 0.95]; it counts in the clutter
    test too, so a track may coast rather than take such a box."""
    confidence_memory: int = 3
    """Updates whose confidences make a track's q for ``confidence_weight``."""

    # --- life cycle ---
    min_hits: int = 3
    """Detections needed before a track is CONFIRMED."""
    max_coast_s: float = 20.0
    """A track not updated for longer than this is LOST (reported once, then removed). The paper ended a track
    after 10 frames, which is 40 s on the challenge frames (~4 s apart) and 0.3 s live (30 ms): neither works
    for both. 20 s bridges up to four missed challenge frames (12 s only two: an occlusion of 10 s between
    frames 4 s apart is a 16 s gap) and, live, a vessel hidden behind another for a while; the gate and the
    clutter test keep the grown prediction from taking a wrong box, and COASTING tells consumers it is one."""
    tentative_max_coast_s: float = 8.5
    """A TENTATIVE track not updated for longer than this is dropped (reported LOST): one missed challenge
    frame (~4 s apart) is tolerated."""
    tentative_max_misses: int = 2
    """A TENTATIVE track is also dropped once it has missed more than this many consecutive frames. This counts
    chances to be detected, not time: on a live camera a false detection that does not repeat within a few
    frames is dropped in milliseconds instead of collecting stray clutter for seconds."""
    max_tracks: int = 100
    """At most this many live tracks; detections that would create more are dropped and counted."""
    duplicate_iou: float = 0.5
    """An unassociated detection overlapping (IoU above this) a detection just associated, or a live track's
    predicted box, is a duplicate box of the same vessel and does not start a new track (0 disables)."""

    # --- input hygiene ---
    min_score: float = 0.0
    """Detections scoring below this are ignored (counted as ``detections_low_score``)."""
    min_box_size_px: float = 1.0
    """Boxes narrower or lower than this, px, are invalid (dropped and counted)."""
    backwards_reset_s: float = 1.0
    """A stamp this many seconds or more before the previous one means a replay restarted: the tracker resets
    (all tracks reported LOST). A smaller step back is an out-of-order frame and is dropped."""
    history_length: int = 50
    """Per-track history (stamps, measured centres and sizes, confidences) keeps at most this many updates: the
    association reads the last ``confidence_memory``, a state file saves them all, so a long one only costs memory."""
    id_prefix: str = "T"
    """Track ids are ``<id_prefix><n>``, n counting from 1 for the whole run (never reused after a reset)."""

    def __post_init__(self) -> None:
        """Validate every field so a bad parameter file fails at start-up with the name of the field."""
        positive = ("measurement_std_px", "gate_px", "gate_sigmas", "max_gate_px", "max_coast_s",
                    "tentative_max_coast_s", "size_log_std", "min_box_size_px")
        non_negative = ("measurement_std_size_frac", "process_noise", "process_noise_y", "clutter_density_per_mpx",
                        "init_velocity_std_x_px_s", "init_velocity_std_y_px_s", "size_weight", "max_size_ratio",
                        "height_log_std", "height_log_std_rate",
                        "duplicate_iou", "min_score", "backwards_reset_s", "confidence_weight")
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise DataError(f"tracker config: {name} must be a finite number > 0, got {value!r}")
        for name in non_negative:
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise DataError(f"tracker config: {name} must be a finite number >= 0, got {value!r}")
        for name, allowed in (("process_noise_model", PROCESS_NOISE_MODELS),
                              ("association", ASSOCIATION_METHODS), ("distance_metric", DISTANCE_METRICS)):
            if getattr(self, name) not in allowed:
                raise DataError(f"tracker config: {name} must be one of {', '.join(allowed)}, "
                                f"got {getattr(self, name)!r}")
        for name, least in (("min_hits", 1), ("max_tracks", 1), ("history_length", 1),
                            ("tentative_max_misses", 0), ("confidence_memory", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                raise DataError(f"tracker config: {name} must be an integer >= {least}, got {value!r}")
        if self.max_gate_px < self.gate_px:
            raise DataError(f"tracker config: max_gate_px ({self.max_gate_px}) must be >= gate_px "
                            f"({self.gate_px})")
        if 0 < self.max_size_ratio <= 1:
            raise DataError(f"tracker config: max_size_ratio must be > 1 (or 0 to disable), "
                            f"got {self.max_size_ratio}")
        if self.duplicate_iou > 1:
            raise DataError(f"tracker config: duplicate_iou must be in [0, 1], got {self.duplicate_iou}")
        if self.size_log_std < 1e-3 or 0 < self.height_log_std < 1e-3:
            raise DataError(f"tracker config: size_log_std must be >= 0.001 and height_log_std 0 (= size_log_std) or "
                            f">= 0.001, got {self.size_log_std} and {self.height_log_std}")

    @classmethod
    def from_dict(cls, values: dict) -> TrackerConfig:
        """Build from a mapping (e.g. ROS parameters), rejecting unknown keys by name."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise DataError(f"tracker config: unknown field(s) {', '.join(unknown)}; "
                            f"known: {', '.join(sorted(known))}")
        return cls(**values)

    def to_dict(self) -> dict:
        """All fields as a plain dict (for parameter files)."""
        return asdict(self)


def node_values(path, node: str = "tracker") -> dict:
    """A parameter YAML's values for ``node``: its ``/**`` block overridden by its own, as ROS merges them.

    A file that cannot be read or parsed is a DataError naming it.
    """
    try:
        blocks = read_params_yaml(path)
    except CalibrationError as error:
        raise DataError(str(error)) from None
    values: dict = {}
    for block in node_blocks(blocks, node):
        values.update(block)
    return values


def load_tracker_config(path, node: str = "tracker") -> TrackerConfig:
    """The tracker settings of a parameter YAML's ``node`` (else ``/**``) block; defaults when ``path`` is None.

    What the tracker node would declare from the same file, so the ROS-free pipeline (and the demo's offline pass)
    tracks with the settings the graph ran with. The node's own keys (topics, QoS, classes) are not tracker
    settings and are skipped; a bad value is a DataError naming it.
    """
    if path is None:
        return TrackerConfig()
    known = {f.name for f in fields(TrackerConfig)}
    values = {k: v for k, v in node_values(path, node).items() if k in known}
    try:
        return TrackerConfig.from_dict(values)
    except (DataError, TypeError, ValueError) as error:
        raise DataError(f"{path}: {error}") from None
