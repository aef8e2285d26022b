"""Launch the canopy_stereo node graph (ROS 2 Jazzy installs).

Live webcams::

    ros2 launch canopy_stereo canopy_stereo.launch.py rig:=/path/rig.yaml left_device:=0 right_device:=2

Bag replay (no cameras; ``bag_play`` publishes the bag's /stereo/*/image_raw)::

    ros2 launch canopy_stereo canopy_stereo.launch.py rig:=.../croton_rig.yaml bag:=.../croton.mcap

Arguments: ``rig`` (default: the paper's rig), ``namespace`` (``/stereo``),
``left_device``/``right_device``, ``fps``, ``matcher`` (``elas``/``sgbm``),
``use_mask`` (``false``), ``bag`` (empty = cameras), ``rate`` (bag speed),
``loop`` (``false``).
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

PACKAGE = "canopy_stereo"


def generate_launch_description():
    rig = LaunchConfiguration("rig")
    ns = LaunchConfiguration("namespace")
    bag = LaunchConfiguration("bag")
    use_bag = PythonExpression(["'", bag, "' != ''"])
    arguments = [
        DeclareLaunchArgument("rig", default_value=PathJoinSubstitution(
            [FindPackageShare(PACKAGE), "config", "paper_rig.yaml"]), description="rig file"),
        DeclareLaunchArgument("namespace", default_value="/stereo"),
        DeclareLaunchArgument("left_device", default_value="0"),
        DeclareLaunchArgument("right_device", default_value="1"),
        DeclareLaunchArgument("fps", default_value="15.0"),
        DeclareLaunchArgument("matcher", default_value="elas"),
        DeclareLaunchArgument("use_mask", default_value="false"),
        DeclareLaunchArgument("bag", default_value="", description="bag to replay instead of cameras"),
        DeclareLaunchArgument("rate", default_value="1.0"),
        DeclareLaunchArgument("loop", default_value="false"),
    ]
    cameras = [
        Node(package=PACKAGE, executable="camera_node", name=f"{side}_camera", namespace=ns,
             condition=UnlessCondition(use_bag),
             parameters=[rig, {"camera_name": side, "device": LaunchConfiguration(f"{side}_device"),
                               "fps": LaunchConfiguration("fps")}])  # rig: <side>/camera_info
        for side in ("left", "right")
    ]
    loop = PythonExpression(["'", LaunchConfiguration("loop"), "'.lower() == 'true'"])
    remaps = [PythonExpression(["'/stereo/", side, "/image_raw:=' + '", ns, "' + '/", side, "/image_raw'"])
              for side in ("left", "right")]
    players = [
        Node(package=PACKAGE, executable="bag_play", name="bag_player",
             condition=IfCondition(PythonExpression([use_bag, " and ", cond])),
             arguments=[bag, "--rate", LaunchConfiguration("rate")] + extra + ["--remap"] + remaps)
        for cond, extra in ((loop, ["--loop"]), (PythonExpression(["not ", loop]), []))
    ]
    processing = [
        Node(package=PACKAGE, executable="rectify_node", namespace=ns, parameters=[rig]),
        Node(package=PACKAGE, executable="disparity_node", namespace=ns,
             parameters=[rig, {"matcher": LaunchConfiguration("matcher")}]),
        Node(package=PACKAGE, executable="segment_node", namespace=ns),
        Node(package=PACKAGE, executable="point_cloud_node", namespace=ns,
             parameters=[rig, {"use_mask": LaunchConfiguration("use_mask")}]),
    ]
    return LaunchDescription(arguments + cameras + players + processing)
