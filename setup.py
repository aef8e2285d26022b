"""ament_python build of canopy_stereo (also a plain pip-installable package)."""
import re
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "canopy_stereo"

#: The version, from package.xml (the one place it is written; ROS tools read it there).
VERSION = re.search(r"<version>\s*([^<\s]+)\s*</version>", open("package.xml", encoding="utf-8").read()).group(1)

#: The viewer's one dependency, pinned (canopy_stereo.viz.RERUN_REQUIREMENT says the same).
RERUN = "rerun-sdk==0.41.0; python_version >= '3.11'"

# ROS 2 executables (`ros2 run canopy_stereo <name>`): name -> module:function.
ROS_EXECUTABLES = {
    "camera_node": "canopy_stereo.ros.nodes.camera:main",
    "rectify_node": "canopy_stereo.ros.nodes.rectify:main",
    "disparity_node": "canopy_stereo.ros.nodes.disparity:main",
    "segment_node": "canopy_stereo.ros.nodes.segment:main",
    "point_cloud_node": "canopy_stereo.ros.nodes.point_cloud:main",
    "bag_record": "canopy_stereo.ros.recorder:main",
    "bag_play": "canopy_stereo.ros.player:main",
    "canopy_graph": "canopy_stereo.ros.canopy_graph:main",
    "fusion_node": "canopy_stereo.ros.fusion_node:main",
    "traits_node": "canopy_stereo.ros.nodes.traits:main",
}

CONSOLE_SCRIPTS = ["canopy-stereo = canopy_stereo.cli:main"] + [
    f"{name} = {target}" for name, target in sorted(ROS_EXECUTABLES.items())
]

setup(
    name=PACKAGE,
    version=VERSION,
    description="Metric stereo reconstruction and measurement of plant canopies (ROS 2 + CLI)",
    long_description=open("README.md", encoding="utf-8").read(),
    long_description_content_type="text/markdown",
    license="Apache-2.0",
    maintainer="canopy_stereo maintainers",
    maintainer_email="maintainers@canopy-stereo.org",
    python_requires=">=3.10",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={PACKAGE: ["data/*", "data/**/*"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/bags", glob("bags/*.mcap") + glob("bags/*.yaml")),
    ],
    install_requires=[
        "setuptools",
        "numpy>=1.24",
        "scipy>=1.10",
        "opencv-python-headless>=4.8",
        "numba>=0.58",
        "pyyaml>=6",
        "mcap>=1.1",
    ],
    extras_require={
        "ros": ["ros-jazzy-rclpy[fastrtps]", "ros-jazzy-common-interfaces"],
        # catkin_pkg: rosidl_adapter (.msg -> .idl) for the test that builds tf2_msgs from its .msg;
        # rerun-sdk: the viewer (canopy-stereo view, run/demo --view), pinned (its web viewer and
        # `rerun` tool ship inside the wheel; the wheel is CPython >= 3.11); CI checks recordings
        # and the web viewer (a 170 MB wheel plus pyarrow)
        # ruff, mypy: the lint and type checks .ci/run runs before the tests (config: pyproject.toml)
        "test": ["pytest>=7", "rosbags>=0.9", "matplotlib>=3.6", "catkin_pkg", "dask[distributed]>=2023.1",
                 "pyarrow>=12", RERUN, "ruff>=0.6", "mypy>=1.11"],
        "plot": ["matplotlib>=3.6"],
        # canopy-stereo batch: Dask distributed (LocalCluster or a cluster); Parquet with pyarrow
        "batch": ["dask[distributed]>=2023.1", "matplotlib>=3.6"],
        "parquet": ["pyarrow>=12"],
        "viz": [RERUN],
    },
    zip_safe=True,
    tests_require=["pytest"],
    entry_points={"console_scripts": CONSOLE_SCRIPTS},
)
