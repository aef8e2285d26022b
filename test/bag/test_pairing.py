"""Approximate- and exact-time pairing edge cases (canopy_stereo.bag.pairing, pure Python)."""
import threading

import pytest

from canopy_stereo.bag.pairing import ApproximateTimePairer, ExactTimeSynchronizer

MS = 1_000_000  # ns


def _run(pairer, events):
    """Feed ``(stream, stamp_ms)`` events; return pairs as stamp tuples (ms) and drops."""
    pairs, drops = [], []
    for stream, t in events:
        pair, dropped = pairer.push(stream, t * MS, (stream, t))
        if pair is not None:
            assert pair.items[0][0] == 0 and pair.items[1][0] == 1
            pairs.append((pair.stamps_ns[0] // MS, pair.stamps_ns[1] // MS))
        drops += [(d.stream, d.stamp_ns // MS) for d in dropped]
    return pairs, drops


def test_pairs_interleaved_webcams_with_jitter():
    # 30 fps webcams, right lags left by 7 ms, with +-2 ms jitter
    events = []
    for k in range(10):
        events += [(0, 33 * k + (k % 3) - 1), (1, 33 * k + 7 - (k % 2))]
    pairs, drops = _run(ApproximateTimePairer(0.015, 3), events)
    assert len(pairs) == 10 and not drops
    assert all(abs(a - b) <= 15 for a, b in pairs)


def test_pair_order_does_not_depend_on_which_camera_arrives_first():
    a = _run(ApproximateTimePairer(0.01), [(0, 0), (1, 3), (0, 33), (1, 36)])
    b = _run(ApproximateTimePairer(0.01), [(1, 3), (0, 0), (1, 36), (0, 33)])
    assert a == b == ([(0, 3), (33, 36)], [])


def test_outside_slop_is_not_paired_and_is_dropped_later():
    pairs, drops = _run(ApproximateTimePairer(0.005, 5), [(0, 0), (1, 20), (0, 33), (1, 35)])
    assert pairs == [(33, 35)]
    assert sorted(drops) == [(0, 0), (1, 20)]  # older than the pair: can never be paired


def test_missing_frame_drops_only_the_orphan():
    # right frame at 33 lost: left 33 is dropped once (0,66)...(66,67) pairs
    pairs, drops = _run(ApproximateTimePairer(0.01, 5),
                        [(0, 0), (1, 1), (0, 33), (0, 66), (1, 67)])
    assert pairs == [(0, 1), (66, 67)]
    assert drops == [(0, 33)]


def test_nearest_partner_wins_when_several_are_in_slop():
    p = ApproximateTimePairer(0.05, 5)
    _run(p, [(1, 0), (1, 30)])
    pairs, drops = _run(p, [(0, 26)])
    assert pairs == [(26, 30)] and drops == [(1, 0)]


def test_queue_overflow_drops_oldest():
    p = ApproximateTimePairer(0.001, queue_size=2)
    pairs, drops = _run(p, [(0, 0), (0, 10), (0, 20), (0, 30)])
    assert pairs == [] and drops == [(0, 0), (0, 10)]
    assert p.pending() == (2, 0)


def test_late_and_duplicate_frames_are_dropped_with_reason():
    p = ApproximateTimePairer(0.01, 5)
    _run(p, [(0, 100), (1, 101)])
    # late by less than the tolerance: dropped (further back is a time jump, tested below)
    pair, dropped = p.push(0, 95 * MS, "late")
    assert pair is None and "older than the last pair" in dropped[0].reason
    p.push(1, 200 * MS, "a")
    pair, dropped = p.push(1, 200 * MS, "b")
    assert pair is None and dropped[0].reason == "duplicate stamp"


def test_exact_stamps_with_zero_slop():
    pairs, drops = _run(ApproximateTimePairer(0.0), [(0, 5), (1, 6), (1, 10), (0, 10)])
    assert pairs == [(10, 10)] and sorted(drops) == [(0, 5), (1, 6)]


def test_pair_properties():
    p = ApproximateTimePairer(0.01)
    p.push(0, 100, "l")
    pair, _ = p.push(1, 140, "r")
    assert pair.stamp_ns == 140 and pair.skew_ns == 40 and pair.items == ("l", "r")


def test_invalid_arguments():
    with pytest.raises(ValueError):
        ApproximateTimePairer(-0.1)
    with pytest.raises(ValueError):
        ApproximateTimePairer(0.1, 0)
    with pytest.raises(ValueError):
        ApproximateTimePairer(0.1).push(2, 0, None)


def test_concurrent_pushes_pair_everything_once():
    p = ApproximateTimePairer(0.001, queue_size=1000)
    out, lock = [], threading.Lock()

    def feed(stream):
        for k in range(500):
            pair, _ = p.push(stream, k * 33 * MS, k)
            if pair is not None:
                with lock:
                    out.append(pair.items)

    threads = [threading.Thread(target=feed, args=(s,)) for s in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(out) == [(k, k) for k in range(500)]


def test_exact_synchronizer_three_streams_any_order():
    s = ExactTimeSynchronizer(3, queue_size=4)
    assert s.push(2, 10, "m10")[0] is None
    assert s.push(0, 10, "d10")[0] is None
    items, dropped = s.push(1, 10, "c10")
    assert items == ["d10", "c10", "m10"] and dropped == []


def test_exact_synchronizer_drops_incomplete_older_sets():
    s = ExactTimeSynchronizer(2, queue_size=4)
    s.push(0, 10, "a")              # partner never arrives
    s.push(1, 20, "b")
    items, dropped = s.push(0, 20, "c")
    assert items == ["c", "b"]
    assert [(d.stream, d.stamp_ns) for d in dropped] == [(0, 10)]
    items, dropped = s.push(1, 15, "late")
    assert items is None and "older" in dropped[0].reason


def test_exact_synchronizer_queue_limit():
    s = ExactTimeSynchronizer(2, queue_size=2)
    drops = []
    for t in (1, 2, 3, 4):
        drops += s.push(0, t, t)[1]
    assert [d.stamp_ns for d in drops] == [1, 2] and s.pending() == 2


def test_stamps_jumping_back_reset_the_pairer_once_and_pairing_goes_on():
    jumps = []
    p = ApproximateTimePairer(0.05, 5, on_jump=jumps.append)
    before = [(s, 100_000 + 100 * k + 4 * s) for k in range(5) for s in (0, 1)]
    pairs, drops = _run(p, before)
    assert len(pairs) == 5 and not drops
    # both cameras restart 100 s earlier; an old right frame is still in flight
    after = [(0, 1000), (1, 100_504), (1, 1004)] + [(s, 1000 + 100 * k + 4 * s) for k in range(1, 6) for s in (0, 1)]
    pairs, drops = _run(p, after)
    assert pairs == [(1000 + 100 * k, 1004 + 100 * k) for k in range(6)]
    assert len(jumps) == 1 and jumps[0].stream == 0 and jumps[0].back_s == pytest.approx(99.4)
    assert drops == [(1, 100_504)]  # the stale frame queued before the right camera followed


def test_a_looping_one_frame_source_pairs_every_pass():
    jumps = []
    p = ApproximateTimePairer(0.01, 5, on_jump=jumps.append)
    pairs, _ = _run(p, [(0, 10), (1, 12)] * 3)
    assert pairs == [(10, 12)] * 3 and len(jumps) == 2


def test_exact_synchronizer_resets_on_a_jump_back():
    jumps = []
    s = ExactTimeSynchronizer(2, queue_size=4, jump_tolerance_s=0, on_jump=jumps.append)
    for t in (100, 200, 300):
        s.push(0, t, t)
        assert s.push(1, t, t)[0] == [t, t]
    s.push(0, 400, "stale")                       # its partner is lost in the restart
    assert s.push(0, 10, "a")[0] is None            # left restarts
    assert s.push(1, 10, "b")[0] == ["a", "b"]      # right follows: paired, no second report
    assert s.push(0, 20, "c")[0] is None and s.push(1, 20, "d")[0] == ["c", "d"]
    assert len(jumps) == 1 and jumps[0].from_ns == 400 and jumps[0].to_ns == 10
    assert s.pending() == 0


def test_slop_for_rate_is_half_a_period():
    from canopy_stereo.bag.pairing import slop_for_rate

    assert slop_for_rate(15) == pytest.approx(1 / 30)
    with pytest.raises(ValueError):
        slop_for_rate(0)


def test_exact_synchronizer_lets_the_old_time_line_finish_after_a_jump():
    """A looping 4-frame bag at the point cloud node: colour images (stream 1) run a disparity
    computation ahead of the disparities (stream 0); at the wrap the colour stream jumps first,
    the disparities still in flight complete their sets, then the disparities follow."""
    jumps = []
    s = ExactTimeSynchronizer(2, queue_size=15, on_jump=jumps.append)
    out = []
    pending_disp = []
    # disparities of frames 2, 3 of a pass arrive after the next pass's first colours
    feed = []
    for p in range(3):
        feed += [(1, 0, p), (1, 1, p)]
        feed += pending_disp
        pending_disp = []
        feed += [(0, 0, p), (1, 2, p), (0, 1, p), (1, 3, p)]
        pending_disp = [(0, 2, p), (0, 3, p)]
    feed += pending_disp
    for stream, k, p in feed:
        items, _ = s.push(stream, (1000 + 100 * k) * MS, (p, k))
        if items is not None:
            out.append(items[0])
    assert out == [(p, k) for p in range(3) for k in range(4)]  # nothing lost at the wraps
    assert len(jumps) == 2 and s.pending() == 0


def test_the_camera_that_follows_a_jump_finds_the_other_cameras_new_frames():
    p = ApproximateTimePairer(0.01, 5)
    _run(p, [(0, 1000), (1, 1002), (0, 1100), (1, 1102)])
    # left restarts first and runs 3 frames ahead of the right camera's restart
    pairs, drops = _run(p, [(0, 10), (0, 110), (0, 210), (1, 12), (1, 112), (1, 212)])
    assert pairs == [(10, 12), (110, 112), (210, 212)] and drops == []


def test_drops_of_a_time_jump_say_so_and_others_do_not():
    """``Dropped.after_jump`` (what a node's drop_unpaired counts without logging: the jump is
    logged once) is set exactly on the drops of a jump, for both synchronizers."""
    p = ApproximateTimePairer(0.05, 5)
    for k in range(3):
        p.push(0, (100_000 + 100 * k) * MS, k)
        p.push(1, (100_000 + 100 * k + 4) * MS, k)
    _, stale = p.push(1, 100_504 * MS, "in flight")  # queued, then the cameras restart earlier
    _, jumped = p.push(0, 1000 * MS, "restart")
    assert not stale and [(d.stamp_ns, d.after_jump) for d in jumped] == [(100_504 * MS, True)]
    s = ExactTimeSynchronizer(2, queue_size=1, jump_tolerance_s=0)
    s.push(0, 100, "a")
    _, full = s.push(0, 200, "b")                     # queue of 1 full: an ordinary drop
    assert [(d.stamp_ns, d.after_jump) for d in full] == [(100, False)]
    s = ExactTimeSynchronizer(2, queue_size=4, jump_tolerance_s=0)
    for stamp in (100, 200):
        s.push(0, stamp, stamp)
        s.push(1, stamp, stamp)
    s.push(0, 300, "old")                             # its partner is lost in the restart
    s.push(0, 10, "c")                                # back in time: the old set may still finish
    _, jumped = s.push(1, 10, "d")                    # a set of the new time line completes
    assert [(d.stamp_ns, d.after_jump) for d in jumped] == [(300, True)]


def test_a_stream_that_starts_after_a_jump_completes_the_sets_of_the_new_time_line():
    """disparity_node on a looping bag: rectify_node's camera_infos (streams 2, 3) arrive before
    its images (published once subscribed) and wrap around (a jump); then the same frame
    comes again and again (follow_matcher: the matcher took nothing yet). The images' first
    messages never stepped back, yet they belong with the infos: a set every pass."""
    s = ExactTimeSynchronizer(4, queue_size=5)
    for t in (200, 304, 100):
        s.push(2, t * MS, t)
        s.push(3, t * MS, t)
    sets = [s.push(stream, 100 * MS, stream)[0] for _ in range(3) for stream in (2, 3, 0, 1)]
    assert [x for x in sets if x is not None] == [[0, 1, 2, 3]] * 3


def test_a_stream_stepping_forward_across_a_jump_completes_the_sets_of_the_new_time_line():
    """point_cloud_node on a looping bag: the disparities (stream 0) are a later, sparser choice
    of the colour images' frames (streams 1, 2); they skip from frame 200 of one pass to frame
    304 of the next without stepping back, and then frame 304 comes again and again."""
    s = ExactTimeSynchronizer(3, queue_size=15)
    for stream in (1, 2, 0):
        s.push(stream, 200 * MS, stream)
    for stream in (1, 2):  # the next pass: 200 again (a jump), then 304
        s.push(stream, 200 * MS, stream)
    sets = [s.push(stream, 304 * MS, stream)[0] for _ in range(3) for stream in (1, 2, 0)]
    assert [x for x in sets if x is not None] == [[0, 1, 2]] * 3
