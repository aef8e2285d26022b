"""The DisparityImage conversions' one-pass kernels against the naive numpy they replace."""
import numpy as np
import pytest

from canopy_stereo.disparity.wire import from_wire, to_wire


def _naive_to_wire(d, valid_min, valid_max, doffs, fill):
    valid = (d >= np.float32(valid_min)) & (d <= np.float32(valid_max))
    out = np.where(valid, d - np.float32(doffs), np.float32(fill)).astype(np.float32)
    cols, rows = np.flatnonzero(valid.any(axis=0)), np.flatnonzero(valid.any(axis=1))
    box = (0, 0, 0, 0) if cols.size == 0 else (int(cols[0]), int(rows[0]), int(cols[-1] - cols[0] + 1),
                                               int(rows[-1] - rows[0] + 1))
    return out, box


def _naive_from_wire(w, lo, hi):
    d = w.astype(np.float32, copy=True)
    d[~np.isfinite(d) | (d < np.float32(lo)) | (d > np.float32(hi))] = np.nan
    return d


def _maps(seed):
    rng = np.random.default_rng(seed)
    for k in range(40):
        h, w = (int(v) for v in rng.integers(1, 50, 2))
        d = (rng.random((h, w)) * 100 - 10).astype(np.float32)
        d[rng.random((h, w)) < 0.3] = np.nan
        d[rng.random((h, w)) < 0.05] = np.inf
        d[rng.random((h, w)) < 0.02] = -np.inf
        if k % 7 == 0:
            d[:] = np.nan
        if k % 11 == 0:  # one valid pixel
            d[:] = np.nan
            d[rng.integers(h), rng.integers(w)] = 30.0
        yield d, float(rng.integers(0, 20)) + float(rng.random()), 50.3 + 30 * float(rng.random()), \
            (0.0, 3.7, -2.25)[k % 3]


@pytest.mark.parametrize("seed", [0, 1])
def test_to_wire_is_the_naive_conversion_bit_for_bit(seed):
    for d, lo, hi, doffs in _maps(seed):
        fill = lo - doffs - 1.0
        out, box = to_wire(d, valid_min=lo, valid_max=hi, doffs=doffs, fill=fill)
        ref, ref_box = _naive_to_wire(d, lo, hi, doffs, fill)
        assert out.dtype == np.float32 and np.array_equal(out.view(np.uint32), ref.view(np.uint32))
        assert box == ref_box


@pytest.mark.parametrize("seed", [0, 1])
def test_from_wire_is_the_naive_conversion(seed):
    for d, lo, hi, _ in _maps(seed):
        got, ref = from_wire(d, min_disparity=lo, max_disparity=hi), _naive_from_wire(d, lo, hi)
        assert np.array_equal(np.isnan(got), np.isnan(ref))
        assert np.array_equal(got[~np.isnan(got)], ref[~np.isnan(ref)])


def test_non_contiguous_and_float64_inputs():
    d = np.arange(48, dtype=np.float64).reshape(6, 8)[:, ::2]
    out, box = to_wire(d, valid_min=5, valid_max=40, doffs=1.5, fill=-1)
    ref, ref_box = _naive_to_wire(d.astype(np.float32), 5, 40, 1.5, -1)
    assert np.array_equal(out, ref) and box == ref_box
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        to_wire(np.zeros(5, np.float32), valid_min=0, valid_max=1, doffs=0, fill=-1)


def test_count_nonfinite_is_numpys_count_on_strided_rows():
    """The compiled count of NaN/inf values equals numpy's, on padded rows read in place and on
    a byte-swapped map (numpy's path)."""
    from canopy_stereo.disparity.wire import count_nonfinite

    rng = np.random.default_rng(3)
    padded = (rng.random((31, 47)) * 100).astype(np.float32)
    padded[rng.random(padded.shape) < 0.1] = np.nan
    padded[rng.random(padded.shape) < 0.05] = np.inf
    padded[rng.random(padded.shape) < 0.05] = -np.inf
    padded[0, 0] = np.float32(3.4e38)  # the largest finite floats stay finite
    for values in (padded, padded[:, :40], padded[3:, 5:], padded.astype(">f4")):
        assert count_nonfinite(values) == values.size - np.count_nonzero(np.isfinite(values))
    assert count_nonfinite(np.zeros((5, 5), np.float32)) == 0


def test_to_wire_into_a_given_buffer_and_the_message_built_in_place():
    """``out=`` (a view of a message's buffer) gets the same values and box; disparity_to_msg's
    data, written in place, are the bytes of the wire map as image_to_msg would copy them."""
    pytest.importorskip("rclpy")
    from canopy_stereo.ros.convert import disparity_to_msg, image_to_msg

    for d, lo, hi, doffs in _maps(2):
        ref, ref_box = to_wire(d, valid_min=max(0.0, lo), valid_max=hi, doffs=doffs, fill=lo - doffs - 1.0)
        out = np.full(d.shape, 7.0, np.float32)
        got, box = to_wire(d, valid_min=max(0.0, lo), valid_max=hi, doffs=doffs, fill=lo - doffs - 1.0, out=out)
        assert got is out and box == ref_box and np.array_equal(out.view(np.uint32), ref.view(np.uint32))
        msg = disparity_to_msg(d, 500.0, 0.1, lo, hi, doffs=doffs, stamp_ns=3, frame_id="f")
        expected = image_to_msg(ref, "32FC1", stamp_ns=3, frame_id="f")
        for name in ("height", "width", "encoding", "is_bigendian", "step", "data"):
            assert getattr(msg.image, name) == getattr(expected, name), name
        assert msg.image.header == expected.header
    with pytest.raises(ValueError, match="out must be"):
        to_wire(np.zeros((3, 4), np.float32), valid_min=0, valid_max=1, doffs=0, fill=-1,
                out=np.zeros((4, 3), np.float32))
