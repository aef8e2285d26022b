"""A transform tree over time (what tf2's ``BufferCore`` does), in pure numpy.

Frames form a forest: each frame has at most one parent. A link ``parent -> child`` is
*static* (one transform for all times, ``/tf_static``) or *dynamic* (a history of stamped
transforms, ``/tf``). :meth:`TransformBuffer.lookup` returns ``T_target_source`` at a stamp
by walking both frames up to their common ancestor; each dynamic link on the way is
interpolated between the two samples around the stamp, translation linearly and rotation
by spherical linear interpolation (slerp), as tf2 does. A stamp outside a link's history
is an *extrapolation* and an error (tf2's default), with the link and the time gap named.

A transform ``T_a_b`` is a 4x4 matrix taking coordinates in frame ``b`` to frame ``a``
(``x_a = T_a_b @ x_b``, metres), what a ``TransformStamped`` with ``header.frame_id = a``
and ``child_frame_id = b`` carries. Stamps are integer nanoseconds.
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.frames import quaternion_to_rotation, rotation_to_quaternion
from canopy_stereo.geometry.transforms import invert_transform


class TransformLookupError(CanopyStereoError):
    """No transform between two frames at a stamp (unknown frame, frames not connected,
    or extrapolation beyond a link's history); the message names which."""


def slerp(q0, q1, fraction: float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions ``(x, y, z, w)``: the rotation
    ``fraction`` (0..1) of the way from ``q0`` to ``q1`` along the shorter arc."""
    q0 = np.asarray(q0, np.float64)
    q1 = np.asarray(q1, np.float64)
    dot = float(q0 @ q1)
    if dot < 0.0:  # q and -q are one rotation: take the shorter way
        q1, dot = -q1, -dot
    if dot > 1.0 - 1e-12:  # equal to rounding: sin(theta) would divide 0 by 0
        q = q0 + fraction * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(min(dot, 1.0))
    s = np.sin(theta)
    return (np.sin((1.0 - fraction) * theta) / s) * q0 + (np.sin(fraction * theta) / s) * q1


def _matrix(t, q) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = quaternion_to_rotation(q)
    T[:3, 3] = t
    return T


@dataclass
class _Link:
    parent: str
    static: bool
    stamps: list = field(default_factory=list)        # sorted int ns (dynamic links)
    translations: list = field(default_factory=list)  # (3,) per stamp
    quaternions: list = field(default_factory=list)   # (4,) per stamp
    T_static: np.ndarray | None = None


class TransformBuffer:
    """Stamped transforms of a tree of frames, looked up with interpolation.

    Args:
        cache_s: seconds of history kept per dynamic link (older samples are forgotten, as
            tf2's ``cache_time``, default 10 s).
    """

    def __init__(self, *, cache_s: float = 10.0):
        if not cache_s > 0:
            raise CanopyStereoError(f"cache_s must be positive, got {cache_s}")
        self.cache_ns = int(cache_s * 1e9)
        self._links: dict[str, _Link] = {}

    # ------------------------------------------------------------------ input
    def set_transform(self, parent: str, child: str, T, stamp_ns: int, *, static: bool = False) -> None:
        """Add ``T_parent_child`` (4x4, metres) at ``stamp_ns`` (ignored for a static link).

        A frame gets a new parent when a transform names one (as tf2); a static link
        becomes dynamic and the other way round when the kind changes."""
        if not parent or not child or parent == child:
            raise CanopyStereoError(f"a transform needs two different frames, got {parent!r} -> {child!r}")
        T = np.asarray(T, np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise CanopyStereoError(f"transform {parent} -> {child} must be a finite 4x4 matrix")
        link = self._links.get(child)
        if link is None or link.parent != parent or link.static != static:
            link = self._links[child] = _Link(parent=parent, static=static)
        if static:
            link.T_static = T.copy()
            return
        stamp = int(stamp_ns)
        i = bisect.bisect_left(link.stamps, stamp)
        q = rotation_to_quaternion(T[:3, :3])
        if i < len(link.stamps) and link.stamps[i] == stamp:  # the same stamp again: replace
            link.translations[i], link.quaternions[i] = T[:3, 3].copy(), q
        else:
            link.stamps.insert(i, stamp)
            link.translations.insert(i, T[:3, 3].copy())
            link.quaternions.insert(i, q)
        cut = bisect.bisect_left(link.stamps, link.stamps[-1] - self.cache_ns)
        if cut:
            del link.stamps[:cut], link.translations[:cut], link.quaternions[:cut]

    # ------------------------------------------------------------------ queries
    def frames(self) -> set[str]:
        """Every frame named so far (parents and children)."""
        return set(self._links) | {link.parent for link in self._links.values()}

    def parent(self, frame: str) -> str | None:
        """The frame's parent, or None for a root or an unknown frame."""
        link = self._links.get(frame)
        return None if link is None else link.parent

    def _chain(self, frame: str) -> list[str]:
        """``[frame, parent, grandparent, ..., root]``."""
        out, seen = [frame], {frame}
        while frame in self._links:
            frame = self._links[frame].parent
            if frame in seen:
                raise TransformLookupError(f"the transforms loop at frame {frame!r}")
            seen.add(frame)
            out.append(frame)
        return out

    def _link_at(self, child: str, stamp_ns: int) -> np.ndarray:
        """``T_parent_child`` of one link at ``stamp_ns`` (0 = its latest)."""
        link = self._links[child]
        if link.T_static is not None:  # a static link
            return link.T_static
        stamps = link.stamps
        if stamp_ns == 0:
            return _matrix(link.translations[-1], link.quaternions[-1])
        i = bisect.bisect_left(stamps, stamp_ns)
        if i < len(stamps) and stamps[i] == stamp_ns:
            return _matrix(link.translations[i], link.quaternions[i])
        if i == 0 or i == len(stamps):
            future = i == len(stamps)
            edge = stamps[-1] if future else stamps[0]
            raise TransformLookupError(
                f"extrapolation into the {'future' if future else 'past'}: {link.parent} -> {child} "
                f"requested at {stamp_ns / 1e9:.6f} s, but its {'latest' if future else 'earliest'} "
                f"transform is at {edge / 1e9:.6f} s ({abs(stamp_ns - edge) / 1e9:.3f} s "
                f"{'later' if future else 'earlier'}; {len(stamps)} transform(s) held)")
        s0, s1 = stamps[i - 1], stamps[i]
        f = (stamp_ns - s0) / (s1 - s0)
        t = (1.0 - f) * link.translations[i - 1] + f * link.translations[i]
        return _matrix(t, slerp(link.quaternions[i - 1], link.quaternions[i], f))

    def _latest_common_stamp(self, links: list[str]) -> int:
        """tf2's time 0: the newest stamp every dynamic link on the path has (0 = all static)."""
        ends = [self._links[c].stamps[-1] for c in links if not self._links[c].static]
        return min(ends) if ends else 0

    def lookup(self, target: str, source: str, *, stamp_ns: int = 0) -> np.ndarray:
        """``T_target_source`` (4x4, metres) at ``stamp_ns`` (0 = the latest time every
        dynamic link on the path has). Raises :class:`TransformLookupError`."""
        known = self.frames()
        for name, frame in (("target", target), ("source", source)):
            if frame not in known:
                raise TransformLookupError(f"{name} frame {frame!r} does not exist "
                                           f"(frames: {', '.join(sorted(known)) or 'none'})")
        if target == source:
            return np.eye(4)
        up_s, up_t = self._chain(source), self._chain(target)
        common = next((f for f in up_s if f in set(up_t)), None)
        if common is None:
            raise TransformLookupError(f"{source!r} and {target!r} are not connected (their roots are "
                                       f"{up_s[-1]!r} and {up_t[-1]!r})")
        links_s = up_s[:up_s.index(common)]  # children whose link is on the path
        links_t = up_t[:up_t.index(common)]
        stamp = int(stamp_ns) or self._latest_common_stamp(links_s + links_t)
        T_common_source = np.eye(4)
        for child in links_s:
            T_common_source = self._link_at(child, stamp) @ T_common_source
        T_common_target = np.eye(4)
        for child in links_t:
            T_common_target = self._link_at(child, stamp) @ T_common_target
        return invert_transform(T_common_target) @ T_common_source

    def can_transform(self, target: str, source: str, *, stamp_ns: int = 0) -> bool:
        """Whether :meth:`lookup` would succeed."""
        try:
            self.lookup(target, source, stamp_ns=stamp_ns)
        except TransformLookupError:
            return False
        return True
