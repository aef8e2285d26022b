"""ELAS (Geiger, Roser, Urtasun, ACCV 2010): the whole pipeline on a rectified pair.

Stages (each in its own module): descriptors, support points, Delaunay
triangulation and plane prior, disparity grid, dense MAP matching, left-right
check, small-segment removal, gap interpolation, adaptive mean / median filters.
"""
from __future__ import annotations

import dataclasses
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from canopy_stereo.elas.delaunay import rasterize_triangles_into, triangle_planes
from canopy_stereo.elas.descriptor import compute_descriptors
from canopy_stereo.elas.grid import disparity_grid
from canopy_stereo.elas.matching import match_job, plane_radius, prior_table
from canopy_stereo.elas.parallel import run_row_bands, run_tasks, thread_count
from canopy_stereo.elas.params import ElasParams, make_params
from canopy_stereo.elas.postprocess import (
    adaptive_mean,
    interpolate_gaps,
    left_right_check,
    median_filter,
    partner_cells,
    remove_small_segments,
)
from canopy_stereo.elas.support import SUPPORT_MARGIN, support_points
from canopy_stereo.elas.workspace import Workspace, thread_workspace
from canopy_stereo.errors import ImageError
from canopy_stereo.io.images import to_gray

#: ``match_cells`` covering at most this share of the grid: the left map is matched first
#: and the right one only in its partners' cells (more cells: both at once, the right one
#: in the swept cells; the extra pass cost ~1 ms per 640x480 frame with 94 % of the cells).
PARTNERS_FIRST_MAX_SHARE = 0.75
#: Smallest image side: one support candidate with its four descriptor samples.
MIN_IMAGE_SIZE = 2 * SUPPORT_MARGIN + 1


class ElasWarning(UserWarning):
    """The pair could not be matched (e.g. no texture): the result is all invalid."""


@dataclass
class ElasResult:
    """Everything one ELAS run produced.

    Attributes:
        disp_left: float32 (H, W) left disparity in pixels (``u_right = u_left - d``),
            -1 where invalid; (ceil(H/2), ceil(W/2)) with subsampling.
        disp_right: the same for the right image (``u_left = u_right + d``), or None.
        support: int32 (N, 3) support points ``(u, v, d)``, left-image pixels.
        triangles_left, triangles_right: int32 (T, 3) indices into ``support``.
        timings: stage name -> seconds.
    """

    disp_left: np.ndarray
    disp_right: np.ndarray | None
    support: np.ndarray
    triangles_left: np.ndarray
    triangles_right: np.ndarray
    params: ElasParams
    timings: dict = field(default_factory=dict)


def _prepare(image, name: str) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise ImageError(f"ELAS needs uint8 images; {name} is {image.dtype} "
                         "(convert float images with e.g. "
                         "np.clip(img * 255, 0, 255).astype(np.uint8))")
    if image.ndim not in (2, 3):
        raise ImageError(f"{name} must be grey (H, W) or colour (H, W, 3), "
                         f"got shape {image.shape}")
    if image.size == 0:
        raise ImageError(f"{name} image is empty: shape {image.shape}")
    gray = to_gray(image, name)
    if min(gray.shape) < MIN_IMAGE_SIZE:
        raise ImageError(f"{name} image is {gray.shape[1]}x{gray.shape[0]} pixels; ELAS needs "
                         f"at least {MIN_IMAGE_SIZE}x{MIN_IMAGE_SIZE}")
    return np.ascontiguousarray(gray)


def _check_inputs(left, right) -> tuple[np.ndarray, np.ndarray]:
    gl, gr = _prepare(left, "left"), _prepare(right, "right")
    if gl.shape != gr.shape:
        raise ImageError(f"image sizes differ: left {gl.shape[1]}x{gl.shape[0]}, "
                         f"right {gr.shape[1]}x{gr.shape[0]}")
    return gl, gr


def _postprocess(disp: np.ndarray, offsets: np.ndarray, p: ElasParams, step: int,
                 timings: dict, tag: str, workspace: Workspace) -> np.ndarray:
    """The filters of one map; returns a fresh map (intermediate maps and scratch come
    from ``workspace``, the last filter's output never does)."""
    t = time.perf_counter()
    speckle = int(p.speckle_size) if step == 1 else int(p.speckle_size) // (step * step)
    disp = remove_small_segments(disp, p.speckle_sim_threshold, speckle, workspace=workspace)
    if p.subpixel:
        disp = np.where(disp >= 0, disp + offsets, disp).astype(np.float32)
    timings[f"segments_{tag}"] = time.perf_counter() - t
    t = time.perf_counter()
    gap = int(p.ipol_gap_width) if step == 1 else max(int(p.ipol_gap_width) // step, 1)
    # the workspace's map only when a filter below makes a fresh one
    disp = interpolate_gaps(disp, gap, extrapolate=bool(p.add_corners),
                            workspace=workspace if p.filter_adaptive_mean or p.filter_median
                            else None)
    timings[f"interpolation_{tag}"] = time.perf_counter() - t
    if p.filter_adaptive_mean:
        t = time.perf_counter()
        disp = adaptive_mean(disp, linear=p.adaptive_mean_weights == "linear",
                             workspace=workspace)
        timings[f"adaptive_mean_{tag}"] = time.perf_counter() - t
    if p.filter_median:
        t = time.perf_counter()
        disp = median_filter(disp, workspace=workspace)
        timings[f"median_{tag}"] = time.perf_counter() - t
    return disp


def _image_priors(support: np.ndarray, p: ElasParams, size: tuple[int, int], right_image: bool,
                  workspace: Workspace):
    """One image's prior maps: Delaunay triangles, their planes and prior flags, the
    disparity grid and the triangle map (None for the grid and map when there are no
    triangles), and the seconds of the three stages (GIL-free: the left and right image
    run as two tasks)."""
    w, h = size
    t0 = time.perf_counter()
    vertices, triangles, planes, valid = triangle_planes(support, right_image=right_image)
    t1 = time.perf_counter()
    if len(triangles) == 0:
        return triangles, planes, valid, None, None, (t1 - t0, 0.0, 0.0)
    grid = disparity_grid(support, (w, h), p.grid_size, p.disp_min, p.disp_max,
                          right_image=right_image, workspace=workspace)
    t2 = time.perf_counter()
    tri_map = workspace.array("triangle_map", (h, w), np.int32)
    # subsampled matching reads every second row only
    rasterize_triangles_into(vertices, triangles, tri_map, row_step=2 if p.subsampling else 1)
    return triangles, planes, valid, grid, tri_map, (t1 - t0, t2 - t1, time.perf_counter() - t2)


def _right_cells(cells: np.ndarray, grid_size: int, width: int, disp_min: int,
                 disp_max: int) -> np.ndarray:
    """The right image's grid cells the left-right check can read from the left ``cells``
    (uint8 (gh, gw)): right column ``x`` is the match of left columns ``x + d``, ``d`` in
    ``[disp_min, disp_max]``, so right cell ``j`` is needed when a left cell over columns
    ``[j g + disp_min, (j + 1) g - 1 + disp_max]`` is (``g`` = ``grid_size``)."""
    gw = cells.shape[1]
    j = np.arange(gw)
    lo = np.clip((j * grid_size + disp_min) // grid_size, 0, gw)
    hi = np.clip(np.minimum((j + 1) * grid_size - 1 + disp_max, width - 1) // grid_size + 1, 0, gw)
    counts = np.concatenate([np.zeros((cells.shape[0], 1), np.int64),
                             np.cumsum(cells != 0, axis=1)], axis=1)
    return (counts[:, hi] - counts[:, lo] > 0).astype(np.uint8)


def elas_run(left: np.ndarray, right: np.ndarray, params: ElasParams,
             *, want_right: bool = True, match_cells: np.ndarray | None = None) -> ElasResult:
    """Run ELAS with fully specified ``params`` (see :func:`elas_disparity`).

    ``match_cells``: bool or uint8 (ceil(H / grid_size), ceil(W / grid_size)) grid cells of
    the left image (``grid_size`` pixels square, from the top-left corner) to match
    (nonzero); pixels of the other cells stay invalid (-1) before the filters, and the
    right image is matched only in the cells the left-right check reads (with
    ``want_right=False`` and at most :data:`PARTNERS_FIRST_MAX_SHARE` of the cells: the
    cells of the matched left pixels' partners, the left map matched first; else the left
    cells swept over the disparity range). Support points and
    triangles cover the whole pair. None (default): every cell. The disparities of the
    matched cells are those of the whole pair before the filters (small-segment removal and
    gap interpolation see the unmatched cells as invalid, so they can differ next to them).

    The intermediate maps live in the calling thread's
    :class:`~canopy_stereo.elas.workspace.Workspace` and are reused by its next run
    (about 31 MB kept per thread at 640x480, 130 MB at 1280x960; release them with
    ``thread_workspace().clear()``); the returned arrays are always new.
    """
    params = params.validate()
    gl, gr = _check_inputs(left, right)
    h, w = gl.shape
    # disparities of w or more cannot occur: a smaller search range keeps the per-cell
    # candidate tables (cells x disparities) small; results are unchanged
    p = dataclasses.replace(params, disp_max=max(min(params.disp_max, w - 1), params.disp_min))
    step = 2 if p.subsampling else 1
    out_shape = ((h + step - 1) // step, (w + step - 1) // step)
    timings: dict[str, float] = {}
    # intermediates from this thread's workspace (no fresh pages per frame); the
    # maps returned below are always fresh arrays
    workspace = thread_workspace()
    ws_l, ws_r = workspace.scoped("left"), workspace.scoped("right")

    t = time.perf_counter()
    (desc_l, tex_l), (desc_r, tex_r) = run_tasks(
        lambda: compute_descriptors(gl, workspace=ws_l),
        lambda: compute_descriptors(gr, workspace=ws_r))
    timings["descriptor"] = time.perf_counter() - t

    t = time.perf_counter()
    support = support_points(desc_l, desc_r, tex_l, tex_r, p)
    timings["support"] = time.perf_counter() - t

    t = time.perf_counter()
    (tri_l, planes_l, valid_l, grid_l, map_l, t_l), (tri_r, planes_r, valid_r, grid_r, map_r, t_r) = \
        run_tasks(lambda: _image_priors(support, p, (w, h), False, ws_l),
                  lambda: _image_priors(support, p, (w, h), True, ws_r))
    for name, t_left, t_right in zip(("delaunay", "grid", "raster"), t_l, t_r):
        # with two threads the sides overlap: each stage's time is the slower side's
        timings[name] = t_left + t_right if thread_count() == 1 else max(t_left, t_right)
    if grid_l is None or grid_r is None:
        warnings.warn(f"ELAS found {len(support)} support point(s), too few to triangulate "
                      "(untextured images or a wrong disparity range?): "
                      "the disparity map is all invalid", ElasWarning, stacklevel=3)
        empty = np.full(out_shape, -1.0, np.float32)
        return ElasResult(empty, empty.copy() if want_right else None, support,
                          tri_l, tri_r, params, timings)

    cells_l = cells_r = None
    if match_cells is not None:
        grid_shape = (-(-h // p.grid_size), -(-w // p.grid_size))
        cells_l = np.ascontiguousarray(np.asarray(match_cells) != 0).view(np.uint8)
        if cells_l.shape != grid_shape:
            raise ImageError(f"match_cells must be {grid_shape[0]}x{grid_shape[1]} cells of "
                             f"{p.grid_size} pixels for a {w}x{h} pair, got shape {cells_l.shape}")
        cells_r = _right_cells(cells_l, int(p.grid_size), w, int(p.disp_min), int(p.disp_max))
    radius = plane_radius(p.sigma, p.sradius)
    prior = prior_table(p.beta, p.gamma, p.sigma, radius + 1)
    common = (p.grid_size, prior, radius)
    tail = (int(p.disp_min), int(p.disp_max), int(p.match_texture), step, bool(p.subpixel))
    t = time.perf_counter()
    job_l, disp_l, off_l = match_job(desc_l, desc_r, tex_l, map_l, planes_l, valid_l, *grid_l,  # type: ignore[call-arg, misc]
                                     *common, 1, *tail, cells=cells_l, workspace=ws_l)
    partners_first = cells_l is not None and not want_right and \
        float(np.mean(cells_l)) <= PARTNERS_FIRST_MAX_SHARE
    if partners_first:
        # the left map first: the right one is then matched only in the cells holding a
        # pixel the left-right check reads (its other pixels never reach the output)
        run_row_bands(job_l)
        cells_r = partner_cells(disp_l, step=step, grid_size=int(p.grid_size), image_size=(w, h))
    job_r, disp_r, off_r = match_job(desc_r, desc_l, tex_r, map_r, planes_r, valid_r, *grid_r,  # type: ignore[call-arg, misc]
                                     *common, -1, *tail, cells=cells_r, workspace=ws_r)
    if partners_first:
        run_row_bands(job_r)
    else:
        run_row_bands(job_l, job_r)
    timings["matching"] = time.perf_counter() - t

    t = time.perf_counter()
    disp_l, disp_r = left_right_check(disp_l, disp_r, p.lr_threshold, step=step,
                                      want_right=want_right, workspace=ws_l)
    timings["lr_check"] = time.perf_counter() - t

    if want_right and not p.postprocess_only_left:
        timings_r: dict[str, float] = {}
        disp_l, disp_r = run_tasks(
            lambda: _postprocess(disp_l, off_l, p, step, timings, "left", ws_l),
            lambda: _postprocess(disp_r, off_r, p, step, timings_r, "right", ws_r))
        timings.update(timings_r)
    else:
        disp_l = _postprocess(disp_l, off_l, p, step, timings, "left", ws_l)
    if not want_right:
        disp_r = None
    elif p.postprocess_only_left and p.subpixel:
        disp_r = np.where(disp_r >= 0, disp_r + off_r, disp_r).astype(np.float32)
    return ElasResult(disp_l, disp_r, support, tri_l, tri_r, params, timings)


def elas_disparity(left: np.ndarray, right: np.ndarray, *, preset: str = "robotics", right_map: bool = True,
                   **params):
    """ELAS disparity maps of a rectified pair.

    Args:
        left, right: rectified images of equal size, uint8 grey (H, W) or BGR
            (H, W, 3) (converted to grey). Other dtypes raise
            :class:`~canopy_stereo.errors.ImageError`.
        preset: ``"robotics"`` or ``"middlebury"`` (the original's presets).
        right_map: also return the right disparity map; ``False`` returns ``None``
            in its place and skips its post-processing (it is still matched, the
            left-right check needs it).
        **params: any field of :class:`~canopy_stereo.elas.params.ElasParams`
            (``disp_min``, ``disp_max``, ``support_threshold``, ..., ``subsampling``,
            and the extras ``subpixel``, ``adaptive_mean_weights``).

    Returns:
        ``(disp_left, disp_right)``: float32 (H, W) disparities in pixels,
        ``u_right = u_left - d_left`` and ``u_left = u_right + d_right``, -1 where
        invalid. With ``subsampling`` they are (ceil(H/2), ceil(W/2)), sampled at
        even rows and columns, disparities in full-resolution pixels.

    A pair without texture yields all-invalid maps and an :class:`ElasWarning`.
    """
    result = elas_run(left, right, make_params(preset, **params), want_right=right_map)
    return result.disp_left, result.disp_right
