"""The package's Fast DDS profile: the raw camera images are read over UDP with a 4 MiB receive
buffer, under the topic names each rectify_node resolves (namespace, remappings)."""
import os
import xml.etree.ElementTree as ET

import pytest

pytest.importorskip("rclpy")

from canopy_stereo.ros import context  # noqa: E402

NS = "{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}"


def _raw_readers(path):
    root = ET.parse(path).getroot()
    readers = {r.get("profile_name"): r for r in root.iter(f"{NS}data_reader")}
    return root, {name: r for name, r in readers.items() if name.endswith("image_raw")}


def test_the_raw_image_readers_listen_on_udp_with_a_4_mib_buffer():
    root, raw = _raw_readers(context.FASTDDS_PROFILES)
    assert set(raw) == set(context.RAW_IMAGE_TOPICS)
    for reader in raw.values():
        assert reader.find(f"{NS}unicastLocatorList/{NS}locator/{NS}udpv4") is not None
    sizes = [int(t.text) for t in root.iter(f"{NS}receiveBufferSize")]
    assert sizes == [4 << 20]


@pytest.mark.parametrize("argv, topics", [
    (["n"], ("/stereo/left/image_raw", "/stereo/right/image_raw")),
    (["n", "--ros-args", "-r", "__ns:=/rig2"], ("/rig2/left/image_raw", "/rig2/right/image_raw")),
    (["n", "--ros-args", "-r", "left/image_raw:=/cam0/image_raw", "-r", "rectify_node:right/image_raw:=cam1/image"],
     ("/cam0/image_raw", "/stereo/cam1/image")),
])
def test_raw_image_topics_as_rcl_resolves_them(argv, topics):
    assert context.raw_image_topics(argv) == topics


def test_other_topics_get_a_profile_named_after_them(monkeypatch):
    for k in ("FASTRTPS_DEFAULT_PROFILES_FILE", "RMW_FASTRTPS_USE_QOS_FROM_XML"):
        monkeypatch.delenv(k, raising=False)
    topics = ("/rig2/left/image_raw", "/rig2/right/image_raw")
    assert context.use_bounded_dds_memory(topics)
    path = os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"]
    assert path != str(context.FASTDDS_PROFILES)
    assert set(_raw_readers(path)[1]) == set(topics)
    assert context.use_bounded_dds_memory() and os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(
        context.FASTDDS_PROFILES)
    monkeypatch.setenv("FASTRTPS_DEFAULT_PROFILES_FILE", "/the/users/own.xml")  # the user's: left alone
    assert not context.use_bounded_dds_memory(topics)
    assert os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] == "/the/users/own.xml"
