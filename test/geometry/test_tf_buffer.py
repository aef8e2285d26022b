"""The pure transform buffer against naive references: scipy's Slerp, matrix products
written out link by link, and tf2's rules (exact at samples, extrapolation is an error)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from canopy_stereo.geometry.tf_buffer import TransformBuffer, TransformLookupError, slerp
from canopy_stereo.geometry.transforms import invert_transform, make_transform

S = 1_000_000_000  # ns per second


def random_transform(rng, scale=1.0):
    return make_transform(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-scale, scale, 3))


def test_slerp_equals_scipy(rng):
    for _ in range(50):
        r0, r1 = Rotation.random(2, random_state=rng)
        f = rng.uniform()
        ref = Slerp([0.0, 1.0], Rotation.concatenate([r0, r1]))(f).as_matrix()
        q = slerp(r0.as_quat(), r1.as_quat(), f)
        np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), ref, atol=1e-12)
    # nearly equal rotations (the linear branch) and the shorter arc through -q
    r = Rotation.from_rotvec([0, 0, 1e-5])
    q = slerp([0, 0, 0, 1.0], -r.as_quat(), 0.5)
    np.testing.assert_allclose(Rotation.from_quat(q).as_rotvec(), [0, 0, 0.5e-5], atol=1e-15)


def test_lookup_chains_static_and_dynamic_links_like_written_out_products(rng):
    """base -> arm (dynamic) -> tool (static) -> cam; base -> other (static): any pair of
    frames equals the explicit product of the links (inverted where walked downwards)."""
    buf = TransformBuffer()
    A = [random_transform(rng) for _ in range(3)]   # base -> arm at 0, 1, 2 s
    B, C, D = (random_transform(rng) for _ in range(3))
    for k, T in enumerate(A):
        buf.set_transform("base", "arm", T, k * S)
    buf.set_transform("arm", "tool", B, 0, static=True)
    buf.set_transform("tool", "cam", C, 0, static=True)
    buf.set_transform("base", "other", D, 0, static=True)
    np.testing.assert_allclose(buf.lookup("base", "cam", stamp_ns=1 * S), A[1] @ B @ C, atol=1e-12)
    np.testing.assert_allclose(buf.lookup("cam", "base", stamp_ns=2 * S), invert_transform(A[2] @ B @ C), atol=1e-12)
    np.testing.assert_allclose(buf.lookup("other", "tool", stamp_ns=0), invert_transform(D) @ A[2] @ B, atol=1e-12)
    np.testing.assert_allclose(buf.lookup("tool", "cam"), C, atol=1e-15)     # all static: any time
    # interpolated: translation linear, rotation slerp, at 1.25 s
    T = buf.lookup("base", "arm", stamp_ns=int(1.25 * S))
    np.testing.assert_allclose(T[:3, 3], 0.75 * A[1][:3, 3] + 0.25 * A[2][:3, 3], atol=1e-12)
    ref = Slerp([1.0, 2.0], Rotation.from_matrix(np.stack([A[1][:3, :3], A[2][:3, :3]])))(1.25).as_matrix()
    np.testing.assert_allclose(T[:3, :3], ref, atol=1e-12)
    np.testing.assert_allclose(buf.lookup("base", "cam", stamp_ns=int(1.25 * S)), T @ B @ C, atol=1e-12)


def test_motion_sampled_at_50_hz_interpolates_a_turn_to_micrometres():
    """An arm turning the camera 0.6 m from the axis at 30 deg/s, sampled at 50 Hz: looked up
    between samples, the camera centre is within 20 um of the true circle (chord sag)."""
    buf = TransformBuffer()
    w = np.radians(30.0)

    def truth(t):
        R = Rotation.from_rotvec([0, 0, w * t]).as_matrix()
        return make_transform(R, R @ [0.6, 0, 0])

    for k in range(100):
        buf.set_transform("base_link", "tool0", truth(k * 0.02), k * S // 50)
    for t in np.linspace(0.013, 1.9, 37):
        err = buf.lookup("base_link", "tool0", stamp_ns=int(t * S)) - truth(t)
        assert np.abs(err[:3, 3]).max() < 20e-6 and np.abs(err[:3, :3]).max() < 1e-9


def test_lookup_errors_name_the_problem():
    buf = TransformBuffer()
    buf.set_transform("base", "arm", np.eye(4), 10 * S)
    buf.set_transform("base", "arm", np.eye(4), 11 * S)
    buf.set_transform("world", "island", np.eye(4), 0, static=True)
    with pytest.raises(TransformLookupError, match="source frame 'cam' does not exist"):
        buf.lookup("base", "cam", stamp_ns=10 * S)
    with pytest.raises(TransformLookupError, match="not connected"):
        buf.lookup("island", "arm", stamp_ns=10 * S)
    with pytest.raises(TransformLookupError, match=r"extrapolation into the future: base -> arm .*\(0.500 s later"):
        buf.lookup("base", "arm", stamp_ns=int(11.5 * S))
    with pytest.raises(TransformLookupError, match="extrapolation into the past"):
        buf.lookup("arm", "base", stamp_ns=9 * S)
    assert buf.can_transform("arm", "base", stamp_ns=10 * S) and not buf.can_transform("arm", "base", stamp_ns=12 * S)


def test_latest_common_time_and_cache():
    buf = TransformBuffer(cache_s=1.0)
    for k in range(30):  # 0.1 s apart: 3 s; only the last second is kept
        buf.set_transform("base", "arm", make_transform(None, [k, 0, 0]), k * S // 10)
    buf.set_transform("arm", "tool", make_transform(None, [0, 1, 0]), 2 * S)
    buf.set_transform("arm", "tool", make_transform(None, [0, 2, 0]), int(2.5 * S))
    # time 0: the newest stamp both links have (2.5 s) -> arm at x = 25
    np.testing.assert_allclose(buf.lookup("base", "tool")[:3, 3], [25, 2, 0])
    with pytest.raises(TransformLookupError, match="past"):
        buf.lookup("base", "arm", stamp_ns=int(1.85 * S))   # older than the cache
    np.testing.assert_allclose(buf.lookup("base", "arm", stamp_ns=int(1.95 * S))[:3, 3], [19.5, 0, 0], atol=1e-9)
    # a frame given a new parent is re-attached (as tf2)
    buf.set_transform("world", "arm", np.eye(4), 0, static=True)
    assert buf.parent("arm") == "world" and "base" not in buf.frames()
