"""``camera_info_url``: where a camera driver keeps its calibration (camera_info_manager's rules).

A URL is ``file:///absolute/path.yaml`` or ``package://<package>/<path in its share
folder>``; ``${NAME}`` is replaced by the camera name and ``${ROS_HOME}`` by ``$ROS_HOME``
(default ``~/.ros``). The empty URL means camera_info_manager's default,
``file://${ROS_HOME}/camera_info/${NAME}.yaml``. The file is camera_calibration_parsers'
camera_info YAML (:func:`canopy_stereo.io.calibration_import.ros.load_camera_info_yaml`), which
is also what ``set_camera_info`` writes (only to ``file://`` URLs, as camera_info_manager).
"""
from __future__ import annotations

import os
from pathlib import Path

from canopy_stereo.errors import CalibrationError

#: camera_info_manager's URL when none is given.
DEFAULT_CAMERA_INFO_URL = "file://${ROS_HOME}/camera_info/${NAME}.yaml"


def ros_home() -> Path:
    """``$ROS_HOME``, else ``~/.ros``."""
    return Path(os.environ.get("ROS_HOME") or Path.home() / ".ros")


def _package_share(package: str) -> Path:
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory(package))
    except Exception:  # noqa: BLE001 - ament not installed, or no such package: one message
        if package == "canopy_stereo":  # from a source checkout: the repository holds config/
            return Path(__file__).resolve().parents[2]
        raise CalibrationError(f"camera_info_url: package {package!r} not found (ament index)") from None


def resolve_camera_info_url(url: str, *, camera_name: str) -> tuple[Path, bool]:
    """``(path, writable)`` of ``url`` for camera ``camera_name`` (see the module docstring);
    ``writable`` is True for ``file://`` URLs. Raises :class:`CalibrationError` (one line) for
    another scheme or a package that is not installed."""
    text = (url or DEFAULT_CAMERA_INFO_URL).replace("${NAME}", camera_name).replace("${ROS_HOME}", str(ros_home()))
    if text.startswith("file://"):
        path = Path(text[len("file://"):])
        if not path.is_absolute():
            raise CalibrationError(f"camera_info_url {url!r}: a file:// URL needs an absolute path")
        return path, True
    if text.startswith("package://"):
        package, _, rest = text[len("package://"):].partition("/")
        if not package or not rest:
            raise CalibrationError(f"camera_info_url {url!r}: expected package://<package>/<path>")
        return _package_share(package) / rest, False
    raise CalibrationError(f"camera_info_url {url!r}: unsupported scheme (file:// or package://)")
