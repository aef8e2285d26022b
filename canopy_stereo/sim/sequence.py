"""Field sequences: a stereo rig moving past plants in wind, each camera on its own clock.

A real robot's rig moves while its two free-running webcams expose, each at
its own instant, with its own exposure and white balance, and sends MJPEG.
:func:`render_sequence` renders exactly that, with the truth of every frame:

* rig motion (:class:`RigMotion`): ``along`` the baseline (image right),
  ``across`` it (image up), ``toward`` the plants, at ``speed`` metres per
  second, optionally turning about the rig's vertical axis (``turn_rate``
  degrees per second); the rig passes its calibrated pose half-way through the
  sequence. The scene is moved relative to the rig (the rig file stays the
  rig's calibration), so every truth is in the rig's world frame *at the
  instant it was captured*;
* capture times (:class:`CaptureTiming`): frame ``k`` of the left camera at
  ``k / fps`` seconds, the right camera ``skew`` seconds later (negative:
  earlier), both with optional Gaussian jitter;
* wind of strength ``wind`` (0 = still, 1 = the gentle breeze of
  ``simulate --frames``: leaves turn 1-4 degrees about their bases with periods
  of 2-4 s; ``wind`` scales both the amplitude and the sway frequency, so leaf
  speeds grow as ``wind**2``);
* per-camera sensor response (:class:`~canopy_stereo.sim.sensor.CameraEffects`:
  exposure, gains, white balance) and MJPEG compression (``jpeg_quality``: the
  images are JPEG encoded and decoded, as a webcam's MJPEG stream is; the
  encoded bytes are kept for compressed bags).

Each :class:`SequenceFrame` (a :class:`~canopy_stereo.sim.render.SimResult`) holds the two
images, their capture times, the left view's truth at the left capture instant (world point
and leaf id per pixel, the scene's truth dict with the rig pose and leaf speeds) and the
right view's at the right instant.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from dataclasses import fields as dataclass_fields

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.camera import point_depth
from canopy_stereo.io.image_codec import decode_compressed, encode_compressed
from canopy_stereo.sim.primitives import Leaf
from canopy_stereo.sim.render import SimResult, render_pair
from canopy_stereo.sim.scene import Scene, axis_angle_matrix, place_in_front_of
from canopy_stereo.sim.scenes import build_scene
from canopy_stereo.sim.sensor import CameraEffects

#: Directions of :class:`RigMotion` in the rig anchor frame (x image right, y image down,
#: z away from the cameras): along the baseline, across it (up), toward the plants.
MOTION_DIRECTIONS = {"still": (0.0, 0.0, 0.0), "along": (1.0, 0.0, 0.0), "across": (0.0, -1.0, 0.0),
                     "toward": (0.0, 0.0, 1.0)}

#: Frame rate the scenes' breeze periods are counted in (``Breeze.period`` frames).
BREEZE_FPS = 15.0


@dataclass(frozen=True)
class RigMotion:
    """Constant rig motion relative to the plants.

    Attributes:
        direction: ``still``, ``along`` (the baseline, image right), ``across`` (image
            up) or ``toward`` (the plants) (:data:`MOTION_DIRECTIONS`).
        speed: metres per second (>= 0).
        turn_rate: degrees per second about the rig's vertical axis (positive: the rig
            turns to its right).
    """

    direction: str = "still"
    speed: float = 0.0
    turn_rate: float = 0.0

    def __post_init__(self):
        if self.direction not in MOTION_DIRECTIONS:
            raise CanopyStereoError(f"unknown motion direction {self.direction!r}; choose one of "
                                    f"{', '.join(MOTION_DIRECTIONS)}")
        if not (np.isfinite(self.speed) and self.speed >= 0):
            raise CanopyStereoError(f"speed must be a finite number >= 0 m/s, got {self.speed}")
        if not np.isfinite(self.turn_rate):
            raise CanopyStereoError(f"turn rate must be finite, got {self.turn_rate}")

    def pose(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Rig pose ``(R (3, 3), d (3,) mm)`` at ``t_s`` seconds from its calibrated pose,
        in the rig anchor frame: a point ``p`` fixed to the plants is at ``R.T @ (p - d)``
        in the moving rig's anchor frame."""
        d = 1000.0 * self.speed * t_s * np.asarray(MOTION_DIRECTIONS[self.direction])
        R = axis_angle_matrix([0.0, -1.0, 0.0], np.deg2rad(self.turn_rate) * t_s)
        return R, d


@dataclass(frozen=True)
class CaptureTiming:
    """When each camera captures.

    Attributes:
        fps: frames per second of both cameras.
        skew: seconds the right camera captures after the left one (negative: before).
        jitter: standard deviation (s) of Gaussian capture-time jitter, per camera and frame.
    """

    fps: float = 15.0
    skew: float = 0.0
    jitter: float = 0.0

    def __post_init__(self):
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise CanopyStereoError(f"fps must be > 0, got {self.fps}")
        if not (np.isfinite(self.skew) and abs(self.skew) < 1.0 / self.fps):
            raise CanopyStereoError(f"skew must be shorter than a frame period ({1e3 / self.fps:.1f} ms), "
                                    f"got {self.skew * 1e3:g} ms")
        if not (np.isfinite(self.jitter) and self.jitter >= 0):
            raise CanopyStereoError(f"jitter must be >= 0 s, got {self.jitter}")

    def times(self, n_frames: int, *, seed: int = 0) -> np.ndarray:
        """(n_frames, 2) capture times (s) of the left and right frames."""
        k = np.arange(n_frames, dtype=np.float64) / self.fps
        t = np.column_stack([k, k + self.skew])
        if self.jitter > 0:
            t += np.random.default_rng([int(seed), 0x5C3E]).normal(0.0, self.jitter, t.shape)
        return t


@dataclass
class SequenceFrame(SimResult):
    """One captured stereo frame of a sequence: a :class:`~canopy_stereo.sim.render.SimResult`
    (world frame and unit of the rig) whose two views were captured at their own instants.

    ``left``/``right`` are the images as the cameras deliver them (after JPEG when the
    sequence has a quality); ``xyz_left``, ``leaf_ids_left``, ``labels_left``, ... are the
    left view's truth at ``t_left``, the ``_right`` ones the right view's at ``t_right``;
    ``truth`` is the scene's truth dict at ``t_left`` (see :mod:`canopy_stereo.sim`) plus
    ``t_left``, ``t_right``, ``skew_ms``, ``rig_pose`` (``R``, ``d_mm`` from the calibrated
    pose), ``leaf_speed_mm_s`` (median and max speed of the leaf surfaces from wind),
    ``jpeg_quality`` and ``sequence`` (the :class:`SequenceSpec`).

    Attributes (beyond :class:`~canopy_stereo.sim.render.SimResult`'s):
        index: frame number.
        t_left, t_right: capture times (s) of the two images.
        jpeg_left, jpeg_right: the JPEG bytes (None for lossless sequences).
    """

    index: int = 0
    t_left: float = 0.0
    t_right: float = 0.0
    jpeg_left: bytes | None = None
    jpeg_right: bytes | None = None

    def depth_left(self, rig) -> np.ndarray:
        """(H, W) float64 true depth of the left pixels along the left camera's axis
        (world units, NaN = none)."""
        xyz = self.xyz_left.reshape(-1, 3)
        ok = np.all(np.isfinite(xyz), axis=1)
        depth = np.full(len(xyz), np.nan)
        depth[ok] = point_depth(rig.P_left, xyz[ok])
        return depth.reshape(self.xyz_left.shape[:2])


@dataclass(frozen=True)
class SequenceSpec:
    """Everything that defines a field sequence (see the module docstring).

    Attributes:
        scene: scene name (:data:`~canopy_stereo.sim.scenes.SCENES`).
        seed: scene layout seed (and noise/jitter seed).
        frames: number of stereo frames.
        motion: :class:`RigMotion`.
        timing: :class:`CaptureTiming`.
        wind: wind strength (>= 0; 0 = still, 1 = gentle breeze).
        effects: sensor response of the two cameras (default :class:`CameraEffects`()).
        jpeg_quality: MJPEG quality 1-100, or None for lossless images.
        supersample: anti-aliasing of the renderer.
    """

    scene: str = "croton"
    seed: int = 0
    frames: int = 2
    motion: RigMotion = field(default_factory=RigMotion)
    timing: CaptureTiming = field(default_factory=CaptureTiming)
    wind: float = 0.0
    effects: CameraEffects | None = None
    jpeg_quality: int | None = None
    supersample: int = 2

    def __post_init__(self):
        if self.frames < 1:
            raise CanopyStereoError(f"frames must be >= 1, got {self.frames}")
        if not (np.isfinite(self.wind) and self.wind >= 0):
            raise CanopyStereoError(f"wind must be >= 0, got {self.wind}")
        if self.jpeg_quality is not None and not 1 <= int(self.jpeg_quality) <= 100:
            raise CanopyStereoError(f"JPEG quality must be 1..100, got {self.jpeg_quality}")

    def as_dict(self) -> dict:
        """JSON-ready description (for truth files and bag metadata)."""
        return {"scene": self.scene, "seed": int(self.seed), "frames": int(self.frames),
                "motion": {"direction": self.motion.direction, "speed_m_s": float(self.motion.speed),
                           "turn_rate_deg_s": float(self.motion.turn_rate)},
                "timing": {"fps": float(self.timing.fps), "skew_ms": 1e3 * float(self.timing.skew),
                           "jitter_ms": 1e3 * float(self.timing.jitter)},
                "wind": float(self.wind), "jpeg_quality": self.jpeg_quality,
                "camera_effects": (self.effects or CameraEffects()).as_dict()}


def _sway_angle(breeze, t_s: float, wind: float) -> float:
    """A leaf's sway (radians) at ``t_s`` in wind of strength ``wind`` (0 at t = 0)."""
    w = 2 * np.pi * wind * BREEZE_FPS / breeze.period
    return float(wind * breeze.amplitude * (np.sin(w * t_s + breeze.phase) - np.sin(breeze.phase)))


def _posed_in_wind(base: Scene, t_s: float, wind: float) -> tuple:
    """The rest scene's primitives with every leaf swayed to its pose at ``t_s``."""
    if wind == 0 or not base.breeze:
        return base.primitives
    out = []
    for p in base.primitives:
        b = base.breeze.get(p.leaf_id) if isinstance(p, Leaf) else None
        if b is not None:
            p = p.rotated_about_base(axis_angle_matrix(b.axis, _sway_angle(b, t_s, wind)))
        out.append(p)
    return tuple(out)


def scene_at(base: Scene, rig, t_s: float, *, motion: RigMotion, wind: float = 0.0,
             t_mid: float = 0.0, frame: int = 0) -> Scene:
    """``base`` (a rest scene in the rig anchor frame, mm) at ``t_s`` seconds: leaves in
    wind, seen from the rig moved by ``motion`` (at its calibrated pose at ``t_mid``),
    placed in ``rig``'s world frame and unit."""
    prims = _posed_in_wind(base, t_s, wind)
    R, d = motion.pose(t_s - t_mid)
    still = replace(base, primitives=prims, breeze={}, frame=int(frame))
    moved = still.transformed(R.T, -R.T @ d, 1.0)
    # the anchor is the moving rig's (truth distances are from the cameras at that instant)
    moved = replace(moved, anchor_origin=np.zeros(3), anchor_axes=np.eye(3))
    return place_in_front_of(moved, rig)


def leaf_speeds(base: Scene, t_s: float, *, wind: float, dt: float = 1e-3) -> np.ndarray:
    """Speeds (mm/s) of points spread over every leaf surface from wind alone at ``t_s``."""
    a, b = _posed_in_wind(base, t_s, wind), _posed_in_wind(base, t_s + dt, wind)
    speeds = [np.linalg.norm(q.surface_points(20, 7) - p.surface_points(20, 7), axis=1) / dt
              for p, q in zip(a, b) if isinstance(p, Leaf)]
    return np.concatenate(speeds) if speeds else np.zeros(0)


def jpeg_round_trip(image: np.ndarray, quality: int) -> tuple[np.ndarray, bytes]:
    """``(decoded BGR image, JPEG bytes)`` of a BGR image at ``quality`` (an MJPEG webcam's
    frame), with the package's one codec (:mod:`canopy_stereo.io.image_codec`)."""
    fmt, data = encode_compressed(image, codec="jpeg", quality=quality)
    return decode_compressed(data, fmt), data


def render_sequence(spec: SequenceSpec, rig, *, progress=None):
    """Render the frames of ``spec`` through ``rig`` (a :class:`~canopy_stereo.io.rig.Rig`).

    Yields one :class:`SequenceFrame` per frame (:func:`~canopy_stereo.sim.render.render_pair`
    with the left camera's scene at its capture instant and the right camera's at its own).
    Deterministic for a given spec. ``progress``: optional callable called after each frame.
    """
    effects = spec.effects or CameraEffects()
    base = build_scene(spec.scene, spec.seed)
    times = spec.timing.times(spec.frames, seed=spec.seed)
    t_mid = 0.5 * float(times[-1, 0] + times[0, 0])
    for k in range(spec.frames):
        left_scene, right_scene = (scene_at(base, rig, float(times[k, cam]), motion=spec.motion, wind=spec.wind,
                                            t_mid=t_mid, frame=k) for cam in (0, 1))
        sim = render_pair(left_scene, rig, supersample=spec.supersample, effects=effects, right_scene=right_scene)
        images, jpegs = [sim.left, sim.right], [None, None]
        if spec.jpeg_quality is not None:
            (images[0], jpegs[0]), (images[1], jpegs[1]) = (jpeg_round_trip(im, spec.jpeg_quality)
                                                          for im in images)
        R, d = spec.motion.pose(float(times[k, 0]) - t_mid)
        speeds = leaf_speeds(base, float(times[k, 0]), wind=spec.wind)
        sim.truth.update({"t_left": float(times[k, 0]), "t_right": float(times[k, 1]),
                          "skew_ms": 1e3 * float(times[k, 1] - times[k, 0]),
                          "rig_pose": {"R": R.tolist(), "d_mm": d.tolist()},
                          "leaf_speed_mm_s": {"median": float(np.median(speeds)) if speeds.size else 0.0,
                                              "max": float(speeds.max()) if speeds.size else 0.0},
                          "jpeg_quality": spec.jpeg_quality, "sequence": spec.as_dict()})
        fields = {f.name: getattr(sim, f.name) for f in dataclass_fields(SimResult)}
        fields.update(left=images[0], right=images[1])
        yield SequenceFrame(**fields, index=k, t_left=float(times[k, 0]), t_right=float(times[k, 1]),
                            jpeg_left=jpegs[0], jpeg_right=jpegs[1])
        if progress is not None:
            progress()


def depth_accuracy(frame: SequenceFrame, organized: np.ndarray, rig, *, mask=None) -> tuple[float, float]:
    """``(median relative depth error, density)`` of a reconstruction of ``frame`` against its truth.

    ``organized``: (H, W, 3) reconstructed world points on the raw left pixel grid (NaN =
    none), e.g. :attr:`~canopy_stereo.pipeline.reconstruct.Reconstruction.organized`;
    ``mask``: (H, W) bool pixels to score (default: the leaves at the left instant).
    Depth along the left camera's axis; density: fraction of ``mask`` with a point. The
    error is NaN when no pixel of ``mask`` got a point.
    """
    mask = frame.leaf_ids_left > 0 if mask is None else np.asarray(mask, bool)
    got = mask & np.all(np.isfinite(organized), axis=2) & np.all(np.isfinite(frame.xyz_left), axis=2)
    density = float(got.sum() / max(int(mask.sum()), 1))
    if not got.any():
        return float("nan"), density
    true = point_depth(rig.P_left, frame.xyz_left[got])
    return float(np.median(np.abs(point_depth(rig.P_left, organized[got]) - true) / true)), density
