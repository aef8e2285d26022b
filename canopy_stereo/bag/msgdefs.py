"""Message type names, classes, ``ros2msg`` schema text and CDR bytes for bags.

The bag library's one door to the ROS message packages: it imports them (and
``rclpy.serialization``, for :func:`serialize` / :func:`deserialize`) only when a
message class or object is asked for, so reading and writing CDR bytes needs no ROS.

rosbag2 stores, per topic, the type name (``sensor_msgs/msg/Image``) and the
message definition in ``ros2msg`` form: the type's ``.msg`` text followed by
the text of every nested type, each introduced by a line of 80 ``=`` and
``MSG: package/Type``. The text comes from the ``.msg`` files installed with
the message packages (``share/<package>/msg``); when those are not installed it
is generated from the Python class: the fields only (the classes do not record
the types of constants, and constants are not on the wire), which describes the
same wire format.
"""
from __future__ import annotations

import functools
import importlib
import os
import sys
from pathlib import Path

from canopy_stereo.errors import CanopyStereoError

_SEPARATOR = "=" * 80

# rosidl IDL type names -> .msg primitive names
_IDL_TO_MSG = {
    "boolean": "bool", "octet": "byte", "char": "char", "float": "float32", "double": "float64",
    "int8": "int8", "uint8": "uint8", "int16": "int16", "uint16": "uint16", "int32": "int32",
    "uint32": "uint32", "int64": "int64", "uint64": "uint64", "string": "string",
    "wstring": "wstring",
}


def type_name(msg_or_class) -> str:
    """``"sensor_msgs/msg/Image"`` for a message class or instance."""
    cls = msg_or_class if isinstance(msg_or_class, type) else type(msg_or_class)
    module = cls.__module__.split(".")
    if len(module) < 2 or module[1] not in ("msg", "srv", "action"):
        raise CanopyStereoError(f"{cls.__name__} is not a ROS message class")
    return f"{module[0]}/{module[1]}/{cls.__name__}"


@functools.cache
def message_class(name: str):
    """The Python class of a type name (``"sensor_msgs/msg/Image"`` or ``"sensor_msgs/Image"``)."""
    parts = name.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise CanopyStereoError(f"malformed message type name {name!r}")
    try:
        return getattr(importlib.import_module(f"{parts[0]}.{parts[1]}"), parts[2])
    except (ImportError, AttributeError):
        raise CanopyStereoError(f"message type {name!r} is not installed") from None


def serialize(msg) -> bytes:
    """CDR bytes (with encapsulation header) of a ROS message object."""
    from rclpy.serialization import serialize_message

    return serialize_message(msg)


def deserialize(data: bytes, cls):
    """The ROS message of class ``cls`` held in CDR bytes ``data`` (rclpy's exceptions pass
    through for bytes that are not valid CDR of that type)."""
    from rclpy.serialization import deserialize_message

    return deserialize_message(data, cls)


def _share_dirs(package: str) -> list[Path]:
    dirs = []
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            dirs.append(Path(prefix) / "share" / package)
    dirs.append(Path(sys.prefix) / "share" / package)
    try:
        mod = importlib.import_module(package)
        here = Path(mod.__file__).resolve()  # type: ignore[arg-type]  # None (namespace): TypeError, below
        # <prefix>/lib/pythonX.Y/site-packages/<package>/__init__.py -> <prefix>/share/<package>
        if len(here.parents) > 4:
            dirs.append(here.parents[4] / "share" / package)
        dirs.append(here.parents[1] / "share" / package)
    except (ImportError, TypeError, AttributeError):
        pass
    return dirs


def _msg_file_text(package: str, kind: str, name: str) -> str | None:
    for d in _share_dirs(package):
        path = d / kind / f"{name}.msg"
        if path.is_file():
            return path.read_text(encoding="utf-8")
    return None


def _msg_type_from_idl(t: str) -> tuple[str, str | None]:
    """Map an IDL field type to ``(msg type text, nested type or None)``."""
    suffix = ""
    if t.startswith("sequence<"):
        inner = t[len("sequence<"):-1]
        if "," in inner:
            inner, bound = (s.strip() for s in inner.rsplit(",", 1))
            suffix = f"[<={bound}]"
        else:
            suffix = "[]"
        t = inner
    elif t.endswith("]") and "[" in t:
        t, size = t[:-1].split("[", 1)
        suffix = f"[{size}]"
    if t.startswith("string<") or t.startswith("wstring<"):
        base, bound = t[:-1].split("<", 1)
        return f"{base}<={bound}{suffix}", None
    if "/" in t:
        pkg, nm = t.split("/")[0], t.split("/")[-1]
        return f"{pkg}/{nm}{suffix}", f"{pkg}/msg/{nm}"
    return _IDL_TO_MSG.get(t, t) + suffix, None


def _generated_text(cls) -> str:
    """``.msg`` field lines of a message class (used when no ``.msg`` file is installed)."""
    fields = cls.get_fields_and_field_types()
    return "".join(f"{_msg_type_from_idl(t)[0]} {name}\n" for name, t in fields.items())


def _nested_types(cls) -> list[str]:
    out = []
    for t in cls.get_fields_and_field_types().values():
        nested = _msg_type_from_idl(t)[1]
        if nested and nested not in out:
            out.append(nested)
    return out


def own_definition(name: str) -> str:
    """The ``.msg`` text of one type (without its dependencies)."""
    pkg, kind, nm = name.split("/")
    text = _msg_file_text(pkg, kind, nm)
    return text if text is not None else _generated_text(message_class(name))


@functools.cache
def message_definition(name: str) -> str:
    """Full ``ros2msg`` definition of ``name`` with every nested type, as rosbag2 writes it."""
    name = type_name(message_class(name))
    parts = [own_definition(name).rstrip("\n")]
    seen = {name}
    order = list(_nested_types(message_class(name)))
    i = 0
    while i < len(order):
        dep = order[i]
        i += 1
        if dep in seen:
            continue
        seen.add(dep)
        pkg, _, nm = dep.split("/")
        parts.append(f"{_SEPARATOR}\nMSG: {pkg}/{nm}\n{own_definition(dep).rstrip(chr(10))}")
        order.extend(d for d in _nested_types(message_class(dep)) if d not in seen)
    return "\n".join(parts) + "\n"
