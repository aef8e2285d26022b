"""Packaging contracts: ament_python layout, package.xml, entry points."""
import importlib
import re
import xml.etree.ElementTree as ET

from test.conftest import REPO


def test_package_xml_is_format_3_with_valid_maintainer():
    root = ET.parse(REPO / "package.xml").getroot()
    assert root.tag == "package" and root.get("format") == "3"
    assert root.findtext("name") == "canopy_stereo"
    email = root.find("maintainer").get("email")
    assert re.fullmatch(r"[A-Za-z0-9._%+-]+@[A-Za-z0-9-]+(\.[A-Za-z0-9-]+)*\.[A-Za-z]{2,}", email)
    deps = {e.text for e in root if e.tag.endswith("depend")}
    for dep in ("rclpy", "sensor_msgs", "stereo_msgs", "std_msgs", "python3-numpy", "python3-opencv",
                "python3-scipy"):
        assert dep in deps
    assert root.find("export/build_type").text == "ament_python"
    assert root.findtext("license") == "Apache-2.0"


def test_setup_cfg_installs_scripts_for_ros2_run():
    text = (REPO / "setup.cfg").read_text()
    assert "script_dir=$base/lib/canopy_stereo" in text
    assert "install_scripts=$base/lib/canopy_stereo" in text
    assert (REPO / "resource" / "canopy_stereo").is_file()
    assert "Apache License" in (REPO / "LICENSE").read_text()


def test_every_console_script_resolves():
    namespace = {}
    src = (REPO / "setup.py").read_text()
    block = src[src.index("ROS_EXECUTABLES"):src.index("CONSOLE_SCRIPTS")]
    exec(block, namespace)  # the dict literal only
    targets = dict(namespace["ROS_EXECUTABLES"])
    targets["canopy-stereo"] = "canopy_stereo.cli:main"
    for name, target in targets.items():
        module, func = target.split(":")
        assert callable(getattr(importlib.import_module(module), func)), name


def test_core_has_no_ros_imports():
    # canopy_stereo/bag/msgdefs.py is the bag library's one door to the message packages: it
    # imports them (and rclpy.serialization) inside the functions that need a message object
    door = REPO / "canopy_stereo" / "bag" / "msgdefs.py"
    assert not re.search(r"^(import|from)\s+(rclpy|sensor_msgs|stereo_msgs)", door.read_text(), re.M)
    for path in (REPO / "canopy_stereo").rglob("*.py"):
        if "ros" in path.relative_to(REPO / "canopy_stereo").parts[:1] or path == door:
            continue
        text = path.read_text()
        assert not re.search(r"^\s*(import|from)\s+(rclpy|sensor_msgs|stereo_msgs)", text, re.M), path


def test_one_version_from_package_xml_and_a_ros_changelog():
    """package.xml holds the version; setup.py and canopy_stereo.__version__ read it; CHANGELOG.rst
    is in catkin_generate_changelog's format with a section for it."""
    import canopy_stereo

    version = ET.parse(REPO / "package.xml").getroot().findtext("version")
    assert re.fullmatch(r"\d+\.\d+\.\d+", version)
    assert canopy_stereo.__version__ == version
    setup_py = (REPO / "setup.py").read_text()
    assert "version=VERSION" in setup_py and not re.search(r"version=\s*[\"']\d", setup_py)
    lines = (REPO / "CHANGELOG.rst").read_text().splitlines()
    assert lines[1] == "Changelog for package canopy_stereo" and set(lines[0]) == set(lines[2]) == {"^"}
    headings = [(a, b) for a, b in zip(lines, lines[1:]) if b and set(b) == {"-"} and len(b) == len(a)]
    assert any(re.fullmatch(rf"{re.escape(version)} \(\d{{4}}-\d{{2}}-\d{{2}}\)", a) for a, _ in headings)
