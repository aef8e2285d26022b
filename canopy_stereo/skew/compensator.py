"""Capture-skew compensation of a free-running stereo pair: the one function every entry point calls.

Two free-running webcams expose up to half a frame period apart. On a moving
rig (or with leaves in wind) the right image then shows the scene displaced
by the motion during the skew, and depth is off by about ``v dt / B``
(8 ms at 0.25 m/s with a 30 mm baseline: 6 %). :class:`SkewCompensator` knows
each pair's skew from the two stamps and brings the right image to the left
image's instant -- the pair's stamp, the instant every consumer of the pair
(disparity, clouds, TF lookups) takes it for -- along the right camera's own
image motion between its previous and current frame
(:func:`~canopy_stereo.skew.motion.image_motion`): back towards the previous
frame when the right image is the later one (interpolation), forward along
the same motion when it is the earlier one. The left image is never changed.

It works on the raw (unrectified) images, before rectification, so the node,
``run`` (through the node) and ``batch`` share it unchanged: the motion is a
property of one camera's image stream, independent of the stereo geometry,
and the rectification that follows is the usual one. When it cannot
compensate -- the first frame, a gap or a cut in the right stream, too little
texture, a skew longer than a frame interval -- the pair goes on as it came
and :attr:`SkewReport.reason` says why. A still scene (a rig on a tripod, no wind:
no part of the image would move by :data:`STILL_SHIFT_PX`) needs nothing: after the flow
and its checks the pair goes on as it came (``still``), without the warp (rectification alone:
about 1 ms of CPU less per 640x480 pair).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.skew.motion import (
    ImageMotion,
    check_frames,
    flow_percentile_px,
    move_in_time,
    reduced_grey,
    reduced_motion,
    sample_moved,
)

#: Skews shorter than this (s) need no compensation.
MIN_SKEW_S = 2e-4
#: Longest interval (s) between two right frames across which motion is followed.
MAX_INTERVAL_S = 0.5
#: A pair whose right image would move less than this (pixels, for 99 % of the image: leaves
#: moving in wind in front of a still backdrop count) is still: nothing to compensate (0.05 px
#: is 0.25 % of depth at a 20 px disparity, below ELAS's sub-pixel noise).
STILL_SHIFT_PX = 0.05
#: Percentile of the flow length that decides :data:`STILL_SHIFT_PX`.
STILL_PERCENTILE = 99.0
#: Least fraction of textured pixels for a usable motion.
MIN_TEXTURED = 0.02
#: Least fraction of the textured pixels the motion must explain (less: a cut).
MIN_EXPLAINED = 0.5
#: Widest reduced image (pixels) the motion is computed on by default: the flow scale halves
#: until the frame fits (0.5 up to 800 px wide, 0.25 for 1280x720): the flow sees the scene at
#: one resolution whatever the camera's, so its error relative to the disparities stays what it
#: is at 640x480, at a quarter of the CPU for HD frames.
FLOW_MAX_WIDTH_PX = 400


def default_flow_scale(width: int) -> float:
    """The flow scale (a power of 1/2, at most 0.5) of :class:`SkewCompensator` for frames
    ``width`` pixels wide: the largest that keeps the reduced width within
    :data:`FLOW_MAX_WIDTH_PX`."""
    scale = 0.5
    while width * scale > FLOW_MAX_WIDTH_PX and scale > 1 / 64:
        scale *= 0.5
    return scale


@dataclass(frozen=True)
class SkewReport:
    """What :meth:`SkewCompensator.compensate` did with one pair.

    Attributes:
        skew_ms: right stamp minus left stamp (ms; positive: the right image is later).
        applied: whether the right image was moved to the left image's instant.
        shift_frames: how far the right image was moved in time, in right frame intervals
            (negative: back towards its previous frame); 0 when not applied (but for ``still``).
        shift_px: median image displacement applied (pixels); 0 when not applied; for a
            ``still`` pair the displacement 99 % of the image stays below.
        reason: why it was not applied (empty when applied): ``off``, ``in step`` (no skew),
            ``still`` (the skew moves nothing by :data:`STILL_SHIFT_PX`: no compensation
            needed, none spent) or what prevented it (first frame, a gap, a cut, too little
            texture, a skew longer than a frame interval).
        cost_ms: wall time the compensation took (motion, checks and warp), ms
            (:meth:`SkewCompensator.measure`: motion and checks).
    """

    skew_ms: float
    applied: bool
    shift_frames: float = 0.0
    shift_px: float = 0.0
    reason: str = ""
    cost_ms: float = 0.0


@dataclass(frozen=True)
class SkewShift:
    """How to bring a right image to its left image's instant: ``frames`` right frame
    intervals in time (negative: back towards the previous frame) along ``motion``, the right
    camera's own image motion (:class:`~canopy_stereo.skew.motion.ImageMotion`)."""

    motion: ImageMotion
    frames: float

    def apply(self, image: np.ndarray, *, coords: np.ndarray | None = None) -> np.ndarray:
        """``image`` (the right image the shift was measured on, or its grey) at the left
        image's instant: (H, W[, C]) like ``image`` (edges replicated, :func:`move_in_time`);
        with ``coords`` (H', W', 2) float32, a rectification map of the right camera, the moved
        image already rectified, in one interpolation (:func:`sample_moved`)."""
        if coords is None:
            return move_in_time(image, self.motion, self.frames)
        return sample_moved(image, self.motion, self.frames, coords=coords)


class SkewCompensator:
    """Stateful: holds the previous right frame and its stamp (feed the pairs in stamp order).

    Args:
        enabled: False: report the skew, change nothing (``skew_compensation`` off).
        flow_scale, flow_preset: resolution and DIS preset of the motion
            (:func:`~canopy_stereo.skew.motion.image_motion`); ``flow_scale`` None (the
            default): :func:`default_flow_scale` of the frames' width (0.5 for 640x480,
            0.25 for 1280x720).
        max_interval_s: longest gap between two right frames still followed (s).
    """

    def __init__(self, *, enabled: bool = True, flow_scale: float | None = None, flow_preset: str = "ultrafast",
                 max_interval_s: float = MAX_INTERVAL_S):
        if not max_interval_s > 0:
            raise CanopyStereoError(f"max_interval_s must be > 0, got {max_interval_s}")
        self.enabled = bool(enabled)
        self.flow_scale = None if flow_scale is None else float(flow_scale)
        self.flow_preset = flow_preset
        self.max_interval_s = float(max_interval_s)
        #: (stamp ns, the previous right image, its reduced grey once computed)
        self._previous: tuple[int, np.ndarray, np.ndarray | None] | None = None

    def reset(self) -> None:
        """Forget the previous frame (a new stream: the next pair is a first frame)."""
        self._previous = None

    def observe(self, right: np.ndarray, *, stamp_right_ns: int) -> None:
        """Keep ``right`` as the previous right frame without compensating anything (a pair
        that is not measured but precedes one that is)."""
        self._previous = (int(stamp_right_ns), right, None)

    def compensate(self, left: np.ndarray, right: np.ndarray, *, stamp_left_ns: int,
                   stamp_right_ns: int) -> tuple[np.ndarray, np.ndarray, SkewReport]:
        """``(left, right at the left image's instant, report)`` of one raw pair.

        ``left``, ``right``: uint8 raw images (H, W[, 3]) of the rig's cameras;
        ``stamp_left_ns``, ``stamp_right_ns``: their capture stamps (ns). The inputs are
        not modified; ``right`` is kept as the next pair's previous frame.
        """
        t0 = time.perf_counter()
        shift, report = self.measure(right, stamp_left_ns=stamp_left_ns, stamp_right_ns=stamp_right_ns)
        if shift is None:
            return left, right, report
        moved = shift.apply(right)
        return left, moved, replace(report, cost_ms=1e3 * (time.perf_counter() - t0))

    def measure(self, right: np.ndarray, *, stamp_left_ns: int,
                stamp_right_ns: int) -> tuple[SkewShift | None, SkewReport]:
        """``(shift, report)`` of one raw pair without moving anything: the
        :class:`SkewShift` that brings ``right`` to the left image's instant, or None (and
        :attr:`SkewReport.reason`) when the pair goes on as it came. ``right``: uint8 (H, W)
        grey or (H, W, 3) BGR (give it the same way every pair); kept as the next pair's
        previous frame. ``rectify_node`` applies the shift inside its rectification map
        (:meth:`SkewShift.apply` with ``coords``); :meth:`compensate` applies it to the raw image.
        :attr:`SkewReport.cost_ms` is the time of the motion and the checks.
        """
        t0 = time.perf_counter()
        skew_ns = int(stamp_right_ns) - int(stamp_left_ns)
        skew_ms = skew_ns / 1e6
        previous, self._previous = self._previous, (int(stamp_right_ns), right, None)

        def unchanged(reason: str):
            return None, SkewReport(skew_ms, False, reason=reason, cost_ms=1e3 * (time.perf_counter() - t0))

        if not self.enabled:
            return unchanged("off")
        if abs(skew_ns) < MIN_SKEW_S * 1e9:
            return unchanged("in step")
        if previous is None:
            return unchanged("first frame")
        prev_stamp, prev_right, prev_small = previous
        interval_s = (int(stamp_right_ns) - prev_stamp) / 1e9
        if interval_s <= 0:
            return unchanged("right stamps went back (a new stream)")
        if interval_s > self.max_interval_s:
            return unchanged(f"gap of {interval_s * 1e3:.0f} ms since the previous right frame")
        if prev_right.shape != right.shape:
            return unchanged("the right image size changed")
        frames = -skew_ns / 1e9 / interval_s
        if abs(frames) > 1.0:
            return unchanged(f"skew {skew_ms:.1f} ms is longer than the right frame interval "
                             f"({interval_s * 1e3:.1f} ms)")
        h, w = right.shape[:2]
        scale = default_flow_scale(w) if self.flow_scale is None else self.flow_scale
        check_frames(prev_right, right, scale=scale)
        if prev_small is None:
            prev_small = reduced_grey(prev_right, scale=scale)
        small = reduced_grey(right, scale=scale)
        self._previous = (int(stamp_right_ns), right, small)  # the next pair's previous: reduced once
        motion = reduced_motion(prev_small, small, size=(w, h), preset=self.flow_preset)
        if motion.textured < MIN_TEXTURED:
            return unchanged(f"too little texture ({100 * motion.textured:.1f} % of the pixels)")
        if motion.explained < MIN_EXPLAINED:
            return unchanged(f"a cut: the previous right frame explains {100 * motion.explained:.0f} % "
                             "of this one")
        moving_px = abs(frames) * flow_percentile_px(motion.flow_reduced, size=(w, h), percentile=STILL_PERCENTILE)
        if moving_px < STILL_SHIFT_PX:  # a still scene: the skew shows nothing (no warp needed)
            return None, SkewReport(skew_ms, False, shift_frames=frames, shift_px=moving_px, reason="still",
                                    cost_ms=1e3 * (time.perf_counter() - t0))
        return SkewShift(motion, frames), SkewReport(skew_ms, True, shift_frames=frames,
                                                     shift_px=abs(frames) * motion.median_px,
                                                     cost_ms=1e3 * (time.perf_counter() - t0))
