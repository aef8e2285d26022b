"""Registration of views with unknown poses: features -> ICP -> pose graph.

For each consecutive pair (view ``k-1`` target, view ``k`` source):

1. Coarse: SIFT matches (with affine simulations) between the two left images
   lifted to 3-D and sequential RANSAC rigid fits giving a few distinct
   candidate motions (:mod:`canopy_stereo.fusion.coarse`); views without images
   start from an initial guess (identity by default).
2. Fine: robust point-to-plane ICP on voxel-down-sampled clouds
   (:mod:`canopy_stereo.fusion.icp`) from each candidate, first with a wide then
   a narrow correspondence distance; the candidate whose result overlaps the
   target most wins.
3. Check: the share of the source's points that land within the narrow
   distance of the target (overlap) and the residual must pass thresholds,
   otherwise :class:`~canopy_stereo.fusion.errors.RegistrationError` names the
   pair and the figures: views that do not overlap never produce a pose.

Poses are chained from view 0 (world = view 0's rig frame). With ``loop``
(``"auto"``: when the last view registers onto the first), the closing edge is
added; if the chain and the closing edge disagree by more than a drift can
explain, a pair was registered wrongly and :class:`RegistrationError` says so,
otherwise :func:`~canopy_stereo.fusion.posegraph.optimize_pose_graph`
distributes the drift.

A known hazard, seen on turntables: a pot (or anything turning about its own
axis of symmetry under fixed lights) looks the same from every angle, so its
features and its surface agree on "no motion". Several feature hypotheses
verified by overlap, the overlap threshold (default 50 %) and the loop check
catch it; views must overlap in their leaves, not just in the pot.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.fusion.coarse import FeatureAlignment, align_keypoints, keypoints_3d
from canopy_stereo.fusion.errors import RegistrationError
from canopy_stereo.fusion.icp import IcpResult, IcpTarget, estimate_normals, icp_point_to_plane
from canopy_stereo.fusion.posegraph import PoseGraphEdge, edge_residuals, optimize_pose_graph
from canopy_stereo.fusion.voxel import voxel_downsample
from canopy_stereo.geometry.transforms import invert_transform, transform_points


@dataclass
class RegistrationSettings:
    """Registration parameters (lengths in world units).

    Attributes:
        voxel: down-sampling voxel of the clouds for the final ICP (about the
            depth noise; the candidates are compared on clouds of twice that voxel).
        feature_threshold: RANSAC inlier distance of lifted feature matches
            (default 3 voxels).
        max_distance: wide ICP correspondence distance (default 3 x feature_threshold).
        fine_distance: narrow ICP distance, also the overlap radius (default 2.5 voxels).
        min_overlap: least share of the source within ``fine_distance`` of the target.
        max_rmse: largest accepted ICP residual (default 2 voxels).
        min_feature_inliers: fewest consistent feature matches accepted.
        hypotheses: distinct feature-based motions verified by ICP (largest overlap wins).
        kernel: ICP robust kernel.
        noise: expected point noise, the lower bound of the ICP kernel's spread.
        max_loop_translation, max_loop_rotation_deg: largest accepted disagreement
            between the chained poses and the loop-closing registration (default
            10 voxels, 5 degrees); more means a pair was registered wrongly.
    """

    voxel: float = 3.0
    feature_threshold: float | None = None
    max_distance: float | None = None
    fine_distance: float | None = None
    min_overlap: float = 0.5
    max_rmse: float | None = None
    min_feature_inliers: int = 10
    hypotheses: int = 3
    kernel: str = "tukey"
    noise: float = 0.0
    max_loop_translation: float | None = None
    max_loop_rotation_deg: float = 5.0

    def resolved(self) -> RegistrationSettings:
        """A copy with every default filled in from ``voxel``."""
        if not self.voxel > 0:
            raise CanopyStereoError(f"registration voxel must be positive, got {self.voxel}")
        ft = self.feature_threshold or 3.0 * self.voxel
        return RegistrationSettings(
            voxel=self.voxel, feature_threshold=ft, max_distance=self.max_distance or 3.0 * ft,
            fine_distance=self.fine_distance or 2.5 * self.voxel, min_overlap=self.min_overlap,
            max_rmse=self.max_rmse or 2.0 * self.voxel, min_feature_inliers=self.min_feature_inliers,
            hypotheses=self.hypotheses, kernel=self.kernel, noise=self.noise,
            max_loop_translation=self.max_loop_translation or 10.0 * self.voxel,
            max_loop_rotation_deg=self.max_loop_rotation_deg)


@dataclass
class PairRegistration:
    """Registration of view ``source`` onto view ``target``.

    Attributes:
        target, source: view indices.
        transform: (4, 4) source rig frame -> target rig frame.
        icp: the fine :class:`IcpResult` (its ``rmse`` and ``overlap`` are the residuals).
        features: the :class:`FeatureAlignment`, or None when no images were used.
        initial: how the ICP started (``"features"``, ``"given"``, ``"identity"``).
        candidates: coarse hypotheses tried (the one with the largest ICP overlap won).
    """

    target: int
    source: int
    transform: np.ndarray
    icp: IcpResult
    features: FeatureAlignment | None = None
    initial: str = "features"
    candidates: int = 1


@dataclass
class RegistrationResult:
    """Poses of all views and the registrations behind them.

    Attributes:
        poses: list of (4, 4) rig -> world (world = view 0's rig frame).
        pairs: the sequential registrations, then the loop closure if any.
        loop_closed: whether a closing edge (last -> first) was used.
        residuals_before, residuals_after: per pair ``(translation, rotation deg)``
            disagreement between the chained / optimised poses and the pair's transform.
        notes: messages (e.g. why the loop was not closed).
    """

    poses: list
    pairs: list
    loop_closed: bool
    residuals_before: list = field(default_factory=list)
    residuals_after: list = field(default_factory=list)
    notes: list = field(default_factory=list)


class _Prepared:
    """A view's down-sampled clouds (fine: ``voxel``, coarse: ``2 voxel``), ICP targets
    and keypoints (computed once, reused by every pair the view is part of)."""

    def __init__(self, view, settings: RegistrationSettings):
        self.view = view
        self._settings = settings
        self._keypoints = None
        self.points, self.target = self._level(settings.voxel)
        self.coarse_points, self.coarse_target = self._level(2.0 * settings.voxel)

    def _level(self, voxel):
        pts, _, _ = voxel_downsample(self.view.points, voxel)
        if len(pts) < 30:
            raise RegistrationError(f"view {self.view.name!r} has only {len(pts)} points after "
                                    f"down-sampling to {voxel:g} {self.view.unit}")
        normals, _ = estimate_normals(pts, 20, viewpoint=self.view.camera_centre)
        return pts, IcpTarget(pts, normals)

    @property
    def keypoints(self):
        if self._keypoints is None and self.view.has_image:
            self._keypoints = keypoints_3d(self.view.image, self.view.organized,
                                           max_spread=self._settings.feature_threshold)
        return self._keypoints


def _icp(src_points, target, s: RegistrationSettings, T_init, distance, iterations):
    return icp_point_to_plane(src_points, target, T_init=T_init, max_distance=distance, kernel=s.kernel,
                              min_scale=s.noise, max_iterations=iterations)


def _register(target: _Prepared, source: _Prepared, s: RegistrationSettings, T_init=None,
              use_features: bool = True, indices=(0, 1)) -> PairRegistration:
    """Register ``source`` onto ``target``: candidates from features (or ``T_init``), coarse
    ICP from each, keep the one with the largest overlap, refine it on the fine clouds,
    then check overlap and residual."""
    tname, sname, unit = target.view.name, source.view.name, target.view.unit
    if T_init is not None:
        candidates = [(np.asarray(T_init, np.float64), None, "given")]
    elif use_features and target.view.has_image and source.view.has_image:
        try:
            found = align_keypoints(source.keypoints, target.keypoints, s.feature_threshold,
                                    min_inliers=s.min_feature_inliers, hypotheses=s.hypotheses)
        except RegistrationError as exc:
            raise RegistrationError(f"views {tname!r} and {sname!r} share no consistent features "
                                    f"(do they overlap?): {exc}") from None
        candidates = [(f.transform, f, "features") for f in found]
    else:
        candidates = [(np.eye(4), None, "identity")]
    best, errors = None, []
    for T0, feats, how in candidates:
        try:
            wide = _icp(source.coarse_points, target.coarse_target, s, T0, s.max_distance, 30)
            near = _icp(source.coarse_points, target.coarse_target, s, wide.transform, s.fine_distance, 30)
        except CanopyStereoError as exc:
            errors.append(str(exc))
            continue
        if best is None or (near.overlap, -near.rmse) > (best[0].overlap, -best[0].rmse):
            best = (near, feats, how)
    if best is None:
        raise RegistrationError(f"views {tname!r} and {sname!r} could not be registered: {errors[0]}")
    near, feats, how = best
    try:
        fine = _icp(source.points, target.target, s, near.transform, s.fine_distance, 60)
    except CanopyStereoError as exc:
        raise RegistrationError(f"views {tname!r} and {sname!r} could not be registered: {exc}") from None
    if fine.overlap < s.min_overlap:
        raise RegistrationError(
            f"views {tname!r} and {sname!r} do not overlap: after the best alignment found only "
            f"{fine.overlap:.0%} of the points of {sname!r} lie within {s.fine_distance:g} {unit} of {tname!r} "
            f"(need {s.min_overlap:.0%})")
    if fine.rmse > s.max_rmse:
        raise RegistrationError(
            f"views {tname!r} and {sname!r} register poorly: ICP residual {fine.rmse:.3g} {unit} exceeds "
            f"{s.max_rmse:.3g} {unit}")
    return PairRegistration(target=indices[0], source=indices[1], transform=fine.transform, icp=fine,
                            features=feats, initial=how, candidates=len(candidates))


def register_pair(target_view, source_view, *, settings: RegistrationSettings | None = None,
                  T_init=None, use_features: bool = True) -> PairRegistration:
    """Register ``source_view`` onto ``target_view``; returns the source -> target transform.

    Raises :class:`RegistrationError` when the views do not overlap or fit poorly.
    """
    s = (settings or RegistrationSettings()).resolved()
    if source_view.unit != target_view.unit:
        from canopy_stereo.fusion.views import common_unit

        common_unit([target_view, source_view])
    return _register(_Prepared(target_view, s), _Prepared(source_view, s), s, T_init, use_features)


def register_views(views, settings: RegistrationSettings | None = None, *, loop="auto",
                   use_features: bool = True, initial_poses=None) -> RegistrationResult:
    """Poses of all views by sequential pairwise registration and loop closure.

    Args:
        views: :class:`~canopy_stereo.fusion.views.View` list in capture order
            (consecutive views must overlap).
        settings: :class:`RegistrationSettings`.
        loop: ``True`` (the last view must register onto the first), ``False``, or
            ``"auto"`` (close the loop when that registration succeeds, n >= 3).
        use_features: start each pair from feature matches when both views have images.
        initial_poses: optional list of (4, 4) approximate poses; pairs then start
            from the relative pose they imply instead of feature matches.

    Returns:
        :class:`RegistrationResult` with world = view 0's rig frame.
    """
    from canopy_stereo.fusion.views import common_unit

    common_unit(views)
    s = (settings or RegistrationSettings()).resolved()
    n = len(views)
    if n == 0:
        raise CanopyStereoError("no views to register")
    prepared = [_Prepared(v, s) for v in views]
    poses = [np.eye(4)]
    pairs = []

    def init_between(i, j):
        if initial_poses is None:
            return None
        return invert_transform(initial_poses[i]) @ initial_poses[j]

    for k in range(1, n):
        pr = _register(prepared[k - 1], prepared[k], s, init_between(k - 1, k), use_features, (k - 1, k))
        pairs.append(pr)
        poses.append(poses[-1] @ pr.transform)
    result = RegistrationResult(poses=poses, pairs=pairs, loop_closed=False)
    if n >= 3 and loop:
        try:
            closing = _register(prepared[0], prepared[n - 1], s, init_between(0, n - 1), use_features, (0, n - 1))
        except RegistrationError as exc:
            if loop is True:
                raise RegistrationError(f"loop closure failed: {exc}") from None
            result.notes.append(f"loop not closed: {exc}")
        else:
            pairs.append(closing)
            result.loop_closed = True
    edges = [PoseGraphEdge(p.target, p.source, p.transform, p.icp.information) for p in pairs]
    result.residuals_before = edge_residuals(poses, edges)
    if result.loop_closed:
        dt, dr = result.residuals_before[-1]
        if dt > s.max_loop_translation or dr > s.max_loop_rotation_deg:
            raise RegistrationError(
                f"the loop does not close: chaining the {n - 1} pairwise registrations disagrees with "
                f"registering {views[-1].name!r} onto {views[0].name!r} by {dt:.3g} {views[0].unit} / "
                f"{dr:.2f} deg (limits {s.max_loop_translation:g} / {s.max_loop_rotation_deg:g}), so at "
                "least one pair was registered wrongly; give poses or take views closer together")
        result.poses = optimize_pose_graph(poses, edges, fixed=0)
    result.residuals_after = edge_residuals(result.poses, edges)
    return result


@dataclass
class PoseCheck:
    """How well two views agree under given poses (no registration).

    Attributes:
        target, source: view indices.
        rmse: RMS point-to-plane distance of the source's points near the target, world units.
        overlap: share of the source's points within ``radius`` of the target.
        radius: the overlap radius, world units.
    """

    target: int
    source: int
    rmse: float
    overlap: float
    radius: float


def check_given_poses(views, poses, *, settings: RegistrationSettings | None = None) -> list[PoseCheck]:
    """Residuals of consecutive views placed by given poses (the ``fuse --poses`` report)."""
    from canopy_stereo.fusion.icp import robust_weights

    s = (settings or RegistrationSettings()).resolved()
    out = []
    prepared = [_Prepared(v, s) for v in views]
    for k in range(1, len(views)):
        tgt, src = prepared[k - 1], prepared[k]
        rel = invert_transform(poses[k - 1]) @ poses[k]
        p = transform_points(rel, src.points)
        d, idx = tgt.target.tree.query(p, k=1, distance_upper_bound=s.fine_distance)
        ok = np.isfinite(d)
        ok[ok] &= np.all(np.isfinite(tgt.target.normals[idx[ok]]), axis=1)
        if ok.sum() == 0:
            out.append(PoseCheck(k - 1, k, float("nan"), 0.0, s.fine_distance))
            continue
        r = np.einsum("ni,ni->n", p[ok] - tgt.target.points[idx[ok]], tgt.target.normals[idx[ok]])
        w = robust_weights(r, "tukey", 4.685 * max(1.4826 * float(np.median(np.abs(r))), 1e-12))
        rmse = float(np.sqrt((w * r * r).sum() / max(w.sum(), 1e-12)))
        out.append(PoseCheck(k - 1, k, rmse, float(ok.mean()), s.fine_distance))
    return out
