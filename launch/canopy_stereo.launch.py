"""Launch the canopy_stereo node graph (ROS 2 Jazzy installs), one process per node.

Live webcams::

    ros2 launch canopy_stereo canopy_stereo.launch.py rig:=/path/rig.yaml left_device:=0 right_device:=2 fps:=15

Bag replay (no cameras; ``bag_play`` publishes the bag's /stereo/*/image_raw)::

    ros2 launch canopy_stereo canopy_stereo.launch.py rig:=.../croton_rig.yaml bag:=.../croton.mcap loop:=true

Arguments: ``rig`` (default: the paper's rig), ``namespace`` (``/stereo``),
``left_device``/``right_device`` (V4L2 index, /dev path, video file or image-sequence
pattern), ``fps`` (camera rate; the left/right pairing tolerance is half its period),
``matcher`` (``elas``/``sgbm``), ``use_mask`` (``false``), ``bag`` (empty = cameras),
``rate`` (bag speed), ``loop`` (``false``; the nodes follow the stamps jumping back at
every pass).

Mounted on a robot (REP 105), several rigs side by side: ``parent_frame`` (robot frame, e.g.
``base_link``), ``mount`` (``"[x, y, z, qx, qy, qz, qw]"``: the rig's world frame in
``parent_frame``) or ``camera_mount`` (the raw left camera's optical frame in ``parent_frame``,
from a hand-eye calibration), ``frame_prefix`` (prepended to every frame the rig names) and
``publish_tf`` (``false`` when the robot's URDF owns the camera frames)::

    ros2 launch canopy_stereo canopy_stereo.launch.py namespace:=rig_a frame_prefix:=rig_a/ \
        parent_frame:=base_link mount:="[0.4, 0.25, 1.1, 0, 0, 0.2588, 0.9659]" left_device:=0 right_device:=1
    ros2 launch canopy_stereo canopy_stereo.launch.py namespace:=rig_b frame_prefix:=rig_b/ \
        parent_frame:=base_link mount:="[0.4, -0.25, 0.95, 0, 0, 0, 1]" left_device:=2 right_device:=3

A bag recorded under another namespace (the bundled ``/stereo/...`` bags) is played into
``namespace``.

In bag mode ``rectify_node`` measures the frame period from the stamps and pairs within
half of it. The tests evaluate this file with ``test/support/launch_eval.py`` (launch and
launch_ros are not on PyPI) and start the commands it describes as processes.
"""
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from canopy_stereo.disparity import DEFAULT_MATCHER, matcher_names
from launch import LaunchDescription

PACKAGE = "canopy_stereo"


def generate_launch_description():
    rig = LaunchConfiguration("rig")
    ns = LaunchConfiguration("namespace")
    bag = LaunchConfiguration("bag")
    fps = LaunchConfiguration("fps")
    use_bag = PythonExpression(["'", bag, "' != ''"])
    arguments = [
        DeclareLaunchArgument("rig", default_value=PathJoinSubstitution(
            [FindPackageShare(PACKAGE), "config", "paper_rig.yaml"]), description="rig file"),
        DeclareLaunchArgument("namespace", default_value="/stereo", description="namespace of the nodes"),
        DeclareLaunchArgument("left_device", default_value="0", description="left camera device"),
        DeclareLaunchArgument("right_device", default_value="1", description="right camera device"),
        DeclareLaunchArgument("fps", default_value="15.0", description="camera frame rate (frames/s)"),
        DeclareLaunchArgument("matcher", default_value=DEFAULT_MATCHER, description="disparity matcher",
                              choices=matcher_names()),
        DeclareLaunchArgument("use_mask", default_value="false", description="plant pixels only"),
        DeclareLaunchArgument("segment_depth_cue", default_value="false",
                              description="segment_node seeds GrabCut with the disparity too (near = plant)"),
        DeclareLaunchArgument("elas_subsampling", default_value="false",
                              description="ELAS matches every second row and column (camera rate at 640x480 "
                                          "on 2 cores; the map is repeated over 2x2 blocks)"),
        DeclareLaunchArgument("bag", default_value="", description="bag to replay instead of cameras"),
        DeclareLaunchArgument("rate", default_value="1.0", description="bag playback speed"),
        DeclareLaunchArgument("loop", default_value="false", description="replay the bag until stopped"),
        DeclareLaunchArgument("parent_frame", default_value="",
                              description="robot frame the rig is mounted on ('' = the rig's world frame is a root)"),
        DeclareLaunchArgument("mount", default_value="",
                              description="[x, y, z, qx, qy, qz, qw]: the rig's world frame in parent_frame (m)"),
        DeclareLaunchArgument("camera_mount", default_value="",
                              description="[x, y, z, qx, qy, qz, qw]: the raw left camera's optical frame in "
                                          "parent_frame (hand-eye), instead of mount"),
        DeclareLaunchArgument("frame_prefix", default_value="",
                              description="prepended to every frame the rig names, e.g. rig_a/"),
        DeclareLaunchArgument("publish_tf", default_value="true",
                              description="publish the rig's frames on /tf_static (false: the URDF owns them)"),
        DeclareLaunchArgument("traits", default_value="false",
                              description="run traits_node: live traits on traits (JSON) and traits/markers"),
    ]
    prefix = LaunchConfiguration("frame_prefix")

    def text(name):  # a string parameter, '' included (launch_ros reads a value as YAML: quote it)
        return ["'", LaunchConfiguration(name), "'"]

    def numbers(name):  # a list of numbers, or '' (unset) when the argument is empty
        return PythonExpression(["'", LaunchConfiguration(name), "' or \"''\""])

    cameras = [
        Node(package=PACKAGE, executable="camera_node", name=f"{side}_camera", namespace=ns,
             condition=UnlessCondition(use_bag),
             parameters=[rig, {"camera_name": side, "device": LaunchConfiguration(f"{side}_device"),
                               "fps": fps, "frame_id": [prefix, "left_camera_optical_frame"]}])
        # rig: <side>/camera_info; both cameras in the left optical frame (one stereo frame, REP 104)
        for side in ("left", "right")
    ]
    loop = PythonExpression(["'", LaunchConfiguration("loop"), "'.lower() == 'true'"])
    remaps = [PythonExpression(["'/stereo/", side, "/image_raw:=/' + '", ns, "'.strip('/') + '/", side,
                                "/image_raw'"]) for side in ("left", "right")]
    players = [
        Node(package=PACKAGE, executable="bag_play", name="bag_player", namespace=ns,
             condition=IfCondition(PythonExpression([use_bag, " and ", cond])),
             arguments=[bag, "--rate", LaunchConfiguration("rate")] + extra + ["--remap"] + remaps)
        for cond, extra in ((loop, ["--loop"]), (PythonExpression(["not ", loop]), []))
    ]
    # pairing tolerance: half a frame period at the camera rate; from a bag, measured from its stamps
    camera_fps = PythonExpression(["0.0 if ", use_bag, " else float('", fps, "')"])
    processing = [
        Node(package=PACKAGE, executable="rectify_node", namespace=ns,
             parameters=[rig, {"fps": camera_fps, "frame_prefix": text("frame_prefix"),
                               "parent_frame": text("parent_frame"), "mount": numbers("mount"),
                               "camera_mount": numbers("camera_mount"),
                               "publish_tf": LaunchConfiguration("publish_tf")}]),
        Node(package=PACKAGE, executable="disparity_node", namespace=ns,
             parameters=[rig, {"matcher": LaunchConfiguration("matcher"),
                               "elas.subsampling": LaunchConfiguration("elas_subsampling"),
                               # masked clouds: match only in the plant region of the previous masks
                               "roi": LaunchConfiguration("use_mask")}]),
        # nothing waits for every mask unless use_mask: GrabCut segments the newest image;
        # masked: a mask for every frame the matcher matched (and only for those)
        Node(package=PACKAGE, executable="segment_node", namespace=ns,
             parameters=[{"queue_size": PythonExpression(
                 ["5 if '", LaunchConfiguration("use_mask"), "'.lower() == 'true' else 1"]),
                 "follow_disparity": LaunchConfiguration("use_mask"),
                 "depth_cue": LaunchConfiguration("segment_depth_cue")}]),
        Node(package=PACKAGE, executable="traits_node", namespace=ns,
             condition=IfCondition(LaunchConfiguration("traits")), parameters=[rig]),
        Node(package=PACKAGE, executable="point_cloud_node", namespace=ns,
             parameters=[rig, {"use_mask": LaunchConfiguration("use_mask")}]),
    ]
    return LaunchDescription(arguments + cameras + players + processing)
