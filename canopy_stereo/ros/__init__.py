"""ROS 2 layer: message converters, the nodes and the node graph, bag play and record.

Everything under this package may import ``rclpy`` and the message packages;
the rest of :mod:`canopy_stereo` never does (the MCAP bag library, its message type
names and the time pairing, which import rclpy only to (de)serialize a message object,
are :mod:`canopy_stereo.bag`). Modules:

* :mod:`~canopy_stereo.ros.convert`: ``sensor_msgs``/``stereo_msgs`` <-> numpy.
* :mod:`~canopy_stereo.ros.player`, :mod:`~canopy_stereo.ros.recorder`: ``bag_play``
  and ``bag_record``.
* :mod:`~canopy_stereo.ros.nodes`: the camera, rectify, disparity, segment and
  point-cloud nodes.
* :mod:`~canopy_stereo.ros.graph`: all nodes in one process;
  :mod:`~canopy_stereo.ros.runner` replays a bag through them (``canopy-stereo run`` / ``demo``);
  :mod:`~canopy_stereo.ros.canopy_graph`: the ``canopy_graph`` executable over both.
* :mod:`~canopy_stereo.ros.params`, :mod:`~canopy_stereo.ros.qos`,
  :mod:`~canopy_stereo.ros.context`: rig parameters, QoS profiles, private contexts
  (and the node processes' allocator and middleware memory settings).
* :mod:`~canopy_stereo.ros.limits`: what an incoming message may be, checked on its
  header before anything is decoded.
* :mod:`~canopy_stereo.ros.bundled`: the bundled bags and rig files (and how they are made).
* :mod:`~canopy_stereo.ros.tf`, :mod:`~canopy_stereo.ros.stereo_geometry`,
  :mod:`~canopy_stereo.ros.camera_info`: ``/tf_static`` (live and in bags), the rig's
  geometry for the nodes after rectification, a driver's ``camera_info``
  (frames: :mod:`canopy_stereo.geometry.frames`).

Units: ROS messages carry metres and seconds; stamps are handled internally as
integer nanoseconds.
"""


def require_ros(what: str = "this command") -> None:
    """Raise :class:`~canopy_stereo.errors.CanopyStereoError` unless rclpy and the message
    packages can be imported (the CLI's ROS commands call this first)."""
    from canopy_stereo.errors import CanopyStereoError

    try:
        import rclpy  # noqa: F401
        import sensor_msgs.msg  # noqa: F401
        import stereo_msgs.msg  # noqa: F401
    except ImportError as exc:
        raise CanopyStereoError(
            f"{what} needs ROS 2 Jazzy's rclpy and message packages ({exc.name} is missing): "
            "pip install ros-jazzy-rclpy ros-jazzy-common-interfaces, or source a ROS 2 "
            "installation") from None
