"""Each part of a split recording (``run --record --split-size``) opens alone: rosbags reads it
and resolves the frame of ``points2`` to the camera frames through the part's own
``/tf_static`` (latched topics are repeated at the start of every part)."""
from __future__ import annotations

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

from canopy_stereo.geometry.frames import DEFAULT_FRAMES  # noqa: E402
from canopy_stereo.io.rig import load_rig  # noqa: E402
from canopy_stereo.ros.bundled import RAW_FRAME, bundled_bag, bundled_rig  # noqa: E402
from canopy_stereo.ros.graph import GraphOptions  # noqa: E402
from canopy_stereo.ros.runner import run_bag  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def _part(path):
    """``(tf tree {child: parent}, points2 frame ids)`` read from one file alone by rosbags."""
    from rosbags.highlevel import AnyReader

    tree, cloud_frames = {}, []
    with AnyReader([path]) as reader:
        for conn, _, raw in reader.messages():
            if conn.topic == "/tf_static":
                for t in reader.deserialize(raw, conn.msgtype).transforms:
                    tree[t.child_frame_id] = t.header.frame_id
            elif conn.topic == "/stereo/points2":
                cloud_frames.append(reader.deserialize(raw, conn.msgtype).header.frame_id)
    return tree, cloud_frames


def _root(tree, frame):
    seen = [frame]
    while frame in tree:
        frame = tree[frame]
        assert frame not in seen
        seen.append(frame)
    return frame


def test_every_split_part_resolves_points2_to_the_cameras(tmp_path):
    rig = load_rig(bundled_rig("croton"))
    out = tmp_path / "split.mcap"
    result = run_bag(bundled_bag("croton"), rig, rate=0, record=out, split_size=400_000,
                     options=GraphOptions(segment=False, parameter_services=False))
    parts = result.recorded_files
    assert len(parts) >= 3
    with_clouds = 0
    for part in parts:
        tree, cloud_frames = _part(part)
        assert tree, f"{part.name} has no /tf_static of its own"
        cameras = [RAW_FRAME, *DEFAULT_FRAMES.values()]
        for frame in set(cloud_frames):
            for camera in cameras:  # one tree joins the cloud's frame and every camera frame
                assert _root(tree, frame) == _root(tree, camera), (part.name, frame, camera)
        with_clouds += bool(cloud_frames)
    assert with_clouds >= 2
