"""The bundled bags' raw images carry a frame our /tf_static names (REP 105: a consumer can
place them), the left camera's optical frame for both (image_geometry's one frame per pair)."""
import pytest

pytest.importorskip("rclpy")

from canopy_stereo.bag import BagReader  # noqa: E402
from canopy_stereo.geometry.frames import FrameNames, stereo_transforms  # noqa: E402
from canopy_stereo.geometry.rectification import fusiello_rectify  # noqa: E402
from canopy_stereo.io.rig import load_rig  # noqa: E402
from canopy_stereo.ros.bundled import BUNDLED, bundled_bag, bundled_rig  # noqa: E402

pytestmark = pytest.mark.ros


@pytest.mark.parametrize("scene", list(BUNDLED))
def test_raw_frame_ids_are_named_by_the_rigs_transforms(scene):
    rig = load_rig(bundled_rig(scene))
    rect = fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
    named = {child for _, child, _ in stereo_transforms(rig, rect, names=FrameNames())}
    frames = {m.header.frame_id for _, m in BagReader(bundled_bag(scene)).read(
        ["/stereo/left/image_raw", "/stereo/right/image_raw"])}
    assert frames == {FrameNames().raw_left} and frames <= named
