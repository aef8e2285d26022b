"""A camera driver's ``<camera>/camera_info`` (REP 104) from the rig, for ``camera_node``.

Like usb_cam or v4l2_camera with a calibration file, ``camera_node`` publishes beside
each raw image the ``sensor_msgs/CameraInfo`` of its camera, stamped and framed as the
image: ``K`` and ``D`` of the raw camera, ``R`` the rotation to the rig's rectified
camera and ``P`` the rectified camera's projection (``Tx = -f B`` for the right camera),
i.e. the rig's Fusiello rectification
(:func:`canopy_stereo.geometry.frames.raw_camera_calibration`). image_proc /
stereo_image_proc given these infos rectify exactly as ``rectify_node`` does.

The calibration is a driver's (camera_info_manager's conventions): the ``camera_info_url``
parameter (``file://``, ``package://``, ``${NAME}``, ``${ROS_HOME}``) when set, else the rig
(the same parameters as ``rectify_node``'s: the rig file with ``--params-file``, or
``rig_file``), else ``${ROS_HOME}/camera_info/${NAME}.yaml`` when it exists; without any, no
``camera_info`` is published until ``~/set_camera_info`` (``sensor_msgs/srv/SetCameraInfo``)
gives one, which is also stored in the URL's file (``cameracalibrator``'s commit).
"""
from __future__ import annotations

from sensor_msgs.msg import CameraInfo
from sensor_msgs.srv import SetCameraInfo

from canopy_stereo.errors import CalibrationError, CanopyStereoError, RigError
from canopy_stereo.geometry.frames import FrameNames, optical_frame, raw_camera_calibration, stereo_info_frame
from canopy_stereo.ros.convert import camera_info_matrices, camera_info_msg
from canopy_stereo.ros.params import RIG_PARAMETERS, declare_rig_parameters, rig_from_node, rig_given

CAMERA_SIDES = ("left", "right")


def default_camera_frame(camera_name: str) -> str:
    """Default ``frame_id`` of a camera's images and infos: the left camera's optical frame
    for both cameras of the pair (``left``, ``right``; :func:`~canopy_stereo.geometry.frames.stereo_info_frame`),
    ``<camera_name>_camera_optical_frame`` otherwise."""
    if camera_name in CAMERA_SIDES:
        return stereo_info_frame(FrameNames(), "raw")
    return optical_frame(f"{camera_name}_camera")


class RawCameraInfoPublisher:
    """``<camera_name>/camera_info`` of one raw camera and its ``set_camera_info`` service
    (see module docstring).

    The calibration comes from, in this order: the ``camera_info_url`` parameter when set
    (a camera_info YAML, :mod:`canopy_stereo.io.camera_info_url`); the rig (``left``/``right``
    camera of the rig file); camera_info_manager's default file
    ``${ROS_HOME}/camera_info/${NAME}.yaml`` when it exists. ``~/set_camera_info``
    (``sensor_msgs/srv/SetCameraInfo``, as camera_info_manager serves it, so ROS's
    ``cameracalibrator`` can commit to the node) publishes the new calibration from then on
    and writes it to the ``camera_info_url`` file (``file://`` only; the default URL when none).

    ``of_pair``: one of the two views of a one-device stereo camera (camera_node's ``layout``):
    its parameter is ``<camera_name>.camera_info_url`` and its service
    ``<camera_name>/set_camera_info`` (beside its topics, where cameracalibrator's stereo mode
    looks), so that each side has its own.

    Attributes:
        calibration: the camera's :class:`~canopy_stereo.geometry.frames.CameraCalibration`,
            or None (none found: no camera_info until ``set_camera_info``).
        source: where it came from (for the log).
    """

    def __init__(self, node, camera_name: str, *, of_pair: bool = False):
        self.node = node
        self.camera_name = camera_name
        self.calibration = None
        self.source = ""
        if not node.has_parameter(next(iter(RIG_PARAMETERS))):
            declare_rig_parameters(node)
        url_parameter = f"{camera_name}.camera_info_url" if of_pair else "camera_info_url"
        node.declare_text(url_parameter, "", "calibration file of this camera: file:///path.yaml or "
                          "package://<pkg>/<path>, ${NAME} = camera_name, ${ROS_HOME}; empty = the rig's "
                          "left/right camera, else ${ROS_HOME}/camera_info/${NAME}.yaml when it exists",
                          read_only=True)
        self.url = str(node.get_parameter(url_parameter).value)
        self.publisher = node.make_publisher(CameraInfo, f"{camera_name}/camera_info")
        self.service = node.create_service(SetCameraInfo, f"{camera_name}/set_camera_info" if of_pair
                                           else "~/set_camera_info",
                                           node.guarded(self._on_set_camera_info))
        self.calibration, self.source = self._initial_calibration()
        if self.calibration is None:
            node.get_logger().info(f"camera {camera_name}: no calibration yet, no camera_info "
                                   "(set one with set_camera_info, camera_info_url or a rig)")
        else:
            node.get_logger().info(f"camera {camera_name}: camera_info from {self.source}")

    def _initial_calibration(self):
        from canopy_stereo.io.calibration_import.ros import load_camera_info_yaml
        from canopy_stereo.io.camera_info_url import resolve_camera_info_url

        if self.url:  # an explicit URL must work: a bad one is the node's start-up error
            path, _ = resolve_camera_info_url(self.url, camera_name=self.camera_name)
            if not path.is_file():
                raise CalibrationError(f"camera_info_url {self.url!r}: no file {path}")
            return load_camera_info_yaml(path)[0], str(path)
        if self.camera_name in CAMERA_SIDES:
            try:
                rig = rig_from_node(self.node)
            except RigError as exc:
                if rig_given(self.node):  # a broken rig stops the node (exit 2), as in the other nodes
                    raise
                self.node.get_logger().info(f"camera {self.camera_name}: no rig ({exc})")
            else:
                return raw_camera_calibration(rig, self.camera_name), "the rig"
        path, _ = resolve_camera_info_url("", camera_name=self.camera_name)
        if path.is_file():
            return load_camera_info_yaml(path)[0], str(path)
        return None, ""

    def _on_set_camera_info(self, request, response):
        """Take a calibration (cameracalibrator's commit): publish it and store it."""
        from canopy_stereo.geometry.frames import CameraCalibration
        from canopy_stereo.io.calibration_import.ros import camera_info_yaml, checked_calibration
        from canopy_stereo.io.camera_info_url import resolve_camera_info_url

        info = request.camera_info
        try:
            K, D, R, P = camera_info_matrices(info)
            cal = CameraCalibration(width=int(info.width), height=int(info.height), K=K, D=D, R=R, P=P,
                                    distortion_model=str(info.distortion_model) or "plumb_bob")
            # the same checks as a file (camera matrix, rotation, coefficients for the model)
            cal = checked_calibration(cal, source=f"set_camera_info of {self.camera_name}")
            path, writable = resolve_camera_info_url(self.url, camera_name=self.camera_name)
            if not writable:
                raise CalibrationError(f"camera_info_url {self.url!r} is not a file:// URL: cannot store")
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(path.name + ".tmp")
            tmp.write_text(camera_info_yaml(cal, self.camera_name), encoding="utf-8")
            tmp.replace(path)
        except (CanopyStereoError, OSError) as exc:
            response.success = False
            response.status_message = str(exc)
            self.node.get_logger().warning(f"set_camera_info refused: {exc}")
            return response
        self.calibration, self.source = cal, str(path)
        response.success = True
        response.status_message = f"stored in {path}"
        self.node.get_logger().info(f"camera {self.camera_name}: new calibration, stored in {path}")
        return response

    def publish(self, stamp_ns: int, frame_id: str, image_shape) -> None:
        """Publish the info of a frame of ``image_shape`` (H, W[, C]) just published."""
        c = self.calibration
        if c is None:
            return
        h, w = image_shape[:2]
        if (w, h) != (c.width, c.height):
            self.node.drop(f"frames are {w}x{h} but the calibration ({self.source}) is {c.width}x{c.height}",
                           "camera_info")
            return
        self.publisher.publish(camera_info_msg(c, stamp_ns, frame_id=frame_id))
