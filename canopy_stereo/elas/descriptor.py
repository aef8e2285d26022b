"""ELAS stage 1: the 16-byte gradient descriptor of every pixel.

Gradients are 3x3 Sobel responses on the uint8 image, stored as bytes centred on
128: ``du = sat((left - right) >> 2) + 128`` (horizontal: the column to the left
minus the column to the right, rows weighted 1-2-1) and ``dv = sat((top - bottom)
>> 2) + 128`` (vertical, columns weighted 1-2-1). ``>>`` is an arithmetic shift
(floor division by 4) and ``sat`` clips to 0..255.

The descriptor of pixel (u, v) concatenates 12 ``du`` and 4 ``dv`` samples at
(row, column) offsets :data:`DU_OFFSETS` and :data:`DV_OFFSETS`. It is defined for
``3 <= v <= H-4`` and ``3 <= u <= W-4`` and is all zeros elsewhere (deterministic,
unlike the original's uninitialised border).

Layout: ``desc[v, u, k]`` (H, W, 16) uint8, one 16-byte vector per pixel, so that
a matching cost is one :func:`~canopy_stereo.elas.simd.sad16`.
"""
from __future__ import annotations

import sys

import numpy as np
from numba import njit

from canopy_stereo.elas.simd import DESC_BYTES, sad16, transpose16x16

#: (row, column) offsets of the 12 horizontal-gradient samples (the centre twice).
DU_OFFSETS = ((-2, 0), (-1, -2), (-1, 0), (-1, 2), (0, -1), (0, 0), (0, 0), (0, 1),
              (1, -2), (1, 0), (1, 2), (2, 0))
#: (row, column) offsets of the 4 vertical-gradient samples.
DV_OFFSETS = ((-1, 0), (0, -1), (0, 1), (1, 0))

_DU_DR = np.array([o[0] for o in DU_OFFSETS], dtype=np.int64)
_DU_DC = np.array([o[1] for o in DU_OFFSETS], dtype=np.int64)
_DV_DR = np.array([o[0] for o in DV_OFFSETS], dtype=np.int64)
_DV_DC = np.array([o[1] for o in DV_OFFSETS], dtype=np.int64)

#: Margin (pixels) on every side where the descriptor is zero.
BORDER = 3


@njit(cache=True, inline="always")
def _sat_byte(x):
    y = (x >> 2) + 128
    if y < 0:
        return 0
    if y > 255:
        return 255
    return y


@njit(cache=True, nogil=True)
def _sobel_into(img, du, dv):
    """Fill ``du``, ``dv`` uint8 (H, W) with the gradient bytes of ``img``; 128 (zero
    gradient) on the 1-px border."""
    h, w = img.shape
    du[0, :] = 128
    du[h - 1, :] = 128
    dv[0, :] = 128
    dv[h - 1, :] = 128
    n = w - 2
    for v in range(1, h - 1):
        du[v, 0] = 128
        du[v, w - 1] = 128
        dv[v, 0] = 128
        dv[v, w - 1] = 128
        # rows above/at/below, each at columns u-1 (l), u (c), u+1 (r) for u = 1..w-2
        al, ac, ar = img[v - 1, 0:n], img[v - 1, 1:n + 1], img[v - 1, 2:n + 2]
        bl, br = img[v, 0:n], img[v, 2:n + 2]
        cl, cc, cr = img[v + 1, 0:n], img[v + 1, 1:n + 1], img[v + 1, 2:n + 2]
        out_u = du[v, 1:n + 1]
        out_v = dv[v, 1:n + 1]
        for i in range(n):
            left = np.int32(al[i]) + 2 * np.int32(bl[i]) + np.int32(cl[i])
            right = np.int32(ar[i]) + 2 * np.int32(br[i]) + np.int32(cr[i])
            top = np.int32(al[i]) + 2 * np.int32(ac[i]) + np.int32(ar[i])
            bottom = np.int32(cl[i]) + 2 * np.int32(cc[i]) + np.int32(cr[i])
            out_u[i] = _sat_byte(left - right)
            out_v[i] = _sat_byte(top - bottom)


@njit(cache=True, nogil=True)
def _sobel_bytes(img):
    """``(du, dv)`` uint8 (H, W) gradient bytes; 128 (zero gradient) on the 1-px border."""
    h, w = img.shape
    du = np.empty((h, w), dtype=np.uint8)
    dv = np.empty((h, w), dtype=np.uint8)
    _sobel_into(img, du, dv)
    return du, dv


@njit(cache=True, nogil=True)
def _texture(desc):
    h, w, _ = desc.shape
    flat = desc.reshape(-1)
    centre = np.full(DESC_BYTES, 128, dtype=np.uint8)
    texture = np.zeros((h, w), dtype=np.int32)
    for v in range(BORDER, h - BORDER):
        base = v * w * DESC_BYTES
        for u in range(BORDER, w - BORDER):
            texture[v, u] = sad16(flat, base + u * DESC_BYTES, centre, 0)
    return texture


@njit(cache=True, nogil=True)
def _assemble_bytes(du, dv, du_dr, du_dc, dv_dr, dv_dc):
    """Descriptor (H, W, 16) byte by byte from the offset tables (any byte order)."""
    h, w = du.shape
    desc = np.zeros((h, w, DESC_BYTES), dtype=np.uint8)
    for v in range(BORDER, h - BORDER):
        row = desc[v]
        for k in range(12):
            src = du[v + du_dr[k]]
            c = du_dc[k]
            for u in range(BORDER, w - BORDER):
                row[u, k] = src[u + c]
        for k in range(4):
            src = dv[v + dv_dr[k]]
            c = dv_dc[k]
            for u in range(BORDER, w - BORDER):
                row[u, 12 + k] = src[u + c]
    return desc


@njit(cache=True, inline="always")
def _pack8(b0, b1, b2, b3, b4, b5, b6, b7):
    """Little-endian uint64 from 8 bytes (b0 lowest)."""
    return (np.uint64(b0) | (np.uint64(b1) << np.uint64(8)) | (np.uint64(b2) << np.uint64(16))
            | (np.uint64(b3) << np.uint64(24)) | (np.uint64(b4) << np.uint64(32))
            | (np.uint64(b5) << np.uint64(40)) | (np.uint64(b6) << np.uint64(48))
            | (np.uint64(b7) << np.uint64(56)))


@njit(cache=True, inline="always")
def _centred(x):
    """``|x - 128|`` of a gradient byte, as int32."""
    return abs(np.int32(x) - 128)


@njit(cache=True, nogil=True)
def _assemble_words(du, dv):
    """Descriptor (H, W, 16) written as two little-endian uint64 words per pixel, and
    its texture (H, W) int32 from the same bytes (:func:`_assemble_words_into`)."""
    h, w = du.shape
    desc = np.empty((h, w, DESC_BYTES), dtype=np.uint8)
    texture = np.empty((h, w), dtype=np.int32)
    _assemble_words_into(du, dv, np.empty((h, w), np.uint8), np.empty((h, w), np.uint8), desc,
                         texture)
    return desc, texture


@njit(cache=True, nogil=True)
def _assemble_words_into(du, dv, adu, adv, desc, texture):
    """Fill ``desc`` (H, W, 16) uint8 and ``texture`` (H, W) int32 (``adu``, ``adv``: uint8
    (H, W) scratch for ``|du - 128|``, ``|dv - 128|``).

    The same bytes as :func:`_assemble_bytes` with the offsets of :data:`DU_OFFSETS` and
    :data:`DV_OFFSETS` spelled out, about 3x faster (vectorises over ``u``); the
    :data:`BORDER` margin is zeroed here, so ``desc`` may hold anything before. The
    texture sums the gradients' distances from 128, each computed once per pixel.
    """
    h, w = du.shape
    flat_du, flat_dv = du.reshape(-1), dv.reshape(-1)
    flat_adu, flat_adv = adu.reshape(-1), adv.reshape(-1)
    for i in range(h * w):
        flat_adu[i] = _centred(flat_du[i])
        flat_adv[i] = _centred(flat_dv[i])
    words = desc.reshape(h, w * DESC_BYTES).view(np.uint64).reshape(h, w, 2)
    flat_words = words.reshape(-1)
    flat_bytes = desc.reshape(-1)
    b = BORDER
    n = w - 2 * b
    for v in range(h):
        if v < b or v >= h - b:
            words[v, :, :] = 0
            texture[v, :] = 0
            continue
        words[v, :b, :] = 0
        words[v, w - b:, :] = 0
        texture[v, :b] = 0
        texture[v, w - b:] = 0
        # du samples: (-2,0) (-1,-2) (-1,0) (-1,2) (0,-1) (0,0) (0,0) (0,1)
        #             (1,-2) (1,0) (1,2) (2,0)
        m2c = du[v - 2, b:b + n]
        m1l, m1c, m1r = du[v - 1, b - 2:b - 2 + n], du[v - 1, b:b + n], du[v - 1, b + 2:b + 2 + n]
        z_l, z_c, z_r = du[v, b - 1:b - 1 + n], du[v, b:b + n], du[v, b + 1:b + 1 + n]
        p1l, p1c, p1r = du[v + 1, b - 2:b - 2 + n], du[v + 1, b:b + n], du[v + 1, b + 2:b + 2 + n]
        p2c = du[v + 2, b:b + n]
        # dv samples: (-1,0) (0,-1) (0,1) (1,0)
        vm1, vl, vr, vp1 = dv[v - 1, b:b + n], dv[v, b - 1:b - 1 + n], dv[v, b + 1:b + 1 + n], \
            dv[v + 1, b:b + n]
        tex = texture[v, b:b + n]
        a_m2c = adu[v - 2, b:b + n]
        a_m1l, a_m1c, a_m1r = adu[v - 1, b - 2:b - 2 + n], adu[v - 1, b:b + n], \
            adu[v - 1, b + 2:b + 2 + n]
        a_zl, a_zc, a_zr = adu[v, b - 1:b - 1 + n], adu[v, b:b + n], adu[v, b + 1:b + 1 + n]
        a_p1l, a_p1c, a_p1r = adu[v + 1, b - 2:b - 2 + n], adu[v + 1, b:b + n], \
            adu[v + 1, b + 2:b + 2 + n]
        a_p2c = adu[v + 2, b:b + n]
        a_vm1, a_vl, a_vr, a_vp1 = adv[v - 1, b:b + n], adv[v, b - 1:b - 1 + n], \
            adv[v, b + 1:b + 1 + n], adv[v + 1, b:b + n]
        # the row's words as a 1-D contiguous array: word 2i / 2i+1 of pixel b+i (a 2-D
        # slice has run-time strides and does not vectorise)
        out = flat_words[(v * w + b) * 2:(v * w + b + n) * 2]
        row_bytes = flat_bytes[(v * w + b) * DESC_BYTES:(v * w + b + n) * DESC_BYTES]
        blocks = n - n % 16
        for i in range(0, blocks, 16):
            transpose16x16(m2c, m1l, m1c, m1r, z_l, z_c, z_c, z_r, p1l, p1c, p1r, p2c, vm1, vl,
                           vr, vp1, i, row_bytes, i * DESC_BYTES)
        for i in range(blocks, n):
            out[2 * i] = _pack8(m2c[i], m1l[i], m1c[i], m1r[i], z_l[i], z_c[i], z_c[i], z_r[i])
            out[2 * i + 1] = _pack8(p1l[i], p1c[i], p1r[i], p2c[i], vm1[i], vl[i], vr[i],
                                    vp1[i])
        for i in range(n):      # a loop of its own: it vectorises (the two together do not)
            tex[i] = (np.int32(a_m2c[i]) + np.int32(a_m1l[i]) + np.int32(a_m1c[i])
                      + np.int32(a_m1r[i]) + np.int32(a_zl[i]) + 2 * np.int32(a_zc[i])
                      + np.int32(a_zr[i]) + np.int32(a_p1l[i]) + np.int32(a_p1c[i])
                      + np.int32(a_p1r[i]) + np.int32(a_p2c[i]) + np.int32(a_vm1[i])
                      + np.int32(a_vl[i]) + np.int32(a_vr[i]) + np.int32(a_vp1[i]))


def gradient_bytes(gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sobel gradient bytes ``(du, dv)``, each uint8 (H, W), 128 = no gradient."""
    return _sobel_bytes(np.ascontiguousarray(gray, dtype=np.uint8))


def compute_descriptors(gray: np.ndarray, *, workspace=None) -> tuple[np.ndarray, np.ndarray]:
    """Descriptors and texture of a uint8 grey image (H, W).

    Args:
        gray: uint8 (H, W) image.
        workspace: a :class:`~canopy_stereo.elas.workspace.Workspace` to take the
            arrays from (reused between calls: the results are overwritten by the
            next call with the same workspace); fresh arrays when None.

    Returns:
        desc: uint8 (H, W, 16), ``desc[v, u]`` is the descriptor of pixel (u, v)
            (zeros within :data:`BORDER` pixels of the image edge).
        texture: int32 (H, W), ``sum_k |desc[v, u, k] - 128|`` (0 on the border).
    """
    gray = np.ascontiguousarray(gray, dtype=np.uint8)
    h, w = gray.shape
    if h <= 2 * BORDER or w <= 2 * BORDER:
        return np.zeros((h, w, DESC_BYTES), np.uint8), np.zeros((h, w), np.int32)
    if workspace is None or sys.byteorder != "little":
        du, dv = _sobel_bytes(gray)
        if sys.byteorder == "little":
            return _assemble_words(du, dv)
        desc = _assemble_bytes(du, dv, _DU_DR, _DU_DC, _DV_DR, _DV_DC)
        return desc, _texture(desc)
    du = workspace.array("du", (h, w), np.uint8)
    dv = workspace.array("dv", (h, w), np.uint8)
    desc = workspace.array("desc", (h, w, DESC_BYTES), np.uint8)
    texture = workspace.array("texture", (h, w), np.int32)
    _sobel_into(gray, du, dv)
    _assemble_words_into(du, dv, workspace.array("du_centred", (h, w), np.uint8),
                         workspace.array("dv_centred", (h, w), np.uint8), desc, texture)
    return desc, texture
