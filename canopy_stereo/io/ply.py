"""PLY point clouds: binary little-endian, float32 x y z + uchar red green blue.

Readable by MeshLab, Open3D and CloudCompare. The header carries the world unit
as a comment (``comment unit mm``, read back by :func:`read_ply`) and says it in
words (``comment x y z in millimetres``) so a person opening the file knows the scale.
Every cloud the package writes (``reconstruct``, ``demo``, ``fuse`` of those) is in
millimetres; the ROS messages are in metres (REP 103).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.clouds import check_cloud

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


@dataclass
class PointCloud:
    """Points (N, 3) float in world units, optional colours (N, 3) uint8 RGB."""

    points: np.ndarray
    colors: np.ndarray | None = None
    unit: str | None = None
    extra: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.points)


#: unit -> its name in the header's plain-language comment.
UNIT_NAMES = {"mm": "millimetres", "cm": "centimetres", "m": "metres", "in": "inches", "ft": "feet",
              "um": "micrometres"}

#: The unit of every cloud the package writes.
PLY_UNIT = "mm"


#: numpy dtype -> PLY property type for extra per-vertex properties.
_NUMPY_TO_PLY = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int",
                 "u4": "uint", "f4": "float", "f8": "double"}


def write_ply(path, points, *, colors=None, unit: str = "mm", comments=(), properties=None) -> Path:
    """Write a binary little-endian PLY.

    Args:
        points: (N, 3) coordinates in ``unit``; stored as float32.
        colors: optional (N, 3) uint8 RGB.
        unit: world unit written as ``comment unit <unit>``.
        comments: further header comment lines.
        properties: optional ``{name: (N,) array}`` of extra per-vertex scalars
            (e.g. view counts), written with their own dtype (int/uint 8-32 bit,
            float32/64); :func:`read_ply` returns them in ``PointCloud.extra``.
    """
    path = Path(path)
    pts = check_cloud(points, organized=None, name="points", dtype=np.float32).reshape(-1, 3)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        cols = np.asarray(colors).reshape(-1, 3)
        if len(cols) != len(pts):
            raise CanopyStereoError(f"{len(cols)} colours for {len(pts)} points")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    extra = {}
    for name, values in (properties or {}).items():
        arr = np.asarray(values).ravel()
        code = arr.dtype.str[1:]
        if code not in _NUMPY_TO_PLY or len(arr) != len(pts):
            raise CanopyStereoError(f"PLY property {name!r}: need {len(pts)} values of an 8-64 bit "
                                    f"numeric type, got {len(arr)} of {arr.dtype}")
        extra[name] = arr
        fields.append((name, "<" + code if arr.dtype.itemsize > 1 else code))
    rec = np.empty(len(pts), dtype=fields)
    rec["x"], rec["y"], rec["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    if colors is not None:
        cols = np.clip(cols, 0, 255).astype(np.uint8)
        rec["red"], rec["green"], rec["blue"] = cols[:, 0], cols[:, 1], cols[:, 2]
    for name, arr in extra.items():
        rec[name] = arr
    lines = ["ply", "format binary_little_endian 1.0", f"comment unit {unit}",
             f"comment x y z in {UNIT_NAMES.get(unit, unit)}", "comment generator canopy_stereo"]
    lines += [f"comment {c}" for c in comments]
    lines += [f"element vertex {len(pts)}", "property float x", "property float y", "property float z"]
    if colors is not None:
        lines += ["property uchar red", "property uchar green", "property uchar blue"]
    lines += [f"property {_NUMPY_TO_PLY[arr.dtype.str[1:]]} {name}" for name, arr in extra.items()]
    lines.append("end_header")
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        f.write(("\n".join(lines) + "\n").encode("ascii"))
        f.write(rec.tobytes())
    return path


def read_ply(path) -> PointCloud:
    """Read the vertices of a PLY file (binary little/big endian or ASCII).

    Raises :class:`CanopyStereoError` if the file is not a PLY with x, y, z.
    """
    path = Path(path)
    try:
        f = open(path, "rb")
    except OSError as exc:
        raise CanopyStereoError(f"cannot read {path}: {exc.strerror or exc}") from None
    with f:
        if f.readline().strip() != b"ply":
            raise CanopyStereoError(f"{path} is not a PLY file (first line is not 'ply')")
        fmt, unit, comments = None, None, []
        elements: list = []  # [name, count, [(property, type), ...]]
        while True:
            line = f.readline()
            if not line:
                raise CanopyStereoError(f"{path}: PLY header has no end_header")
            words = line.decode("ascii", "replace").split()
            if not words:
                continue
            if words[0] == "end_header":
                break
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "comment":
                comments.append(" ".join(words[1:]))
                if len(words) >= 3 and words[1] == "unit":
                    unit = words[2]
            elif words[0] == "element":
                elements.append([words[1], int(words[2]), []])
            elif words[0] == "property":
                if not elements:
                    raise CanopyStereoError(f"{path}: property before any element")
                if words[1] == "list":
                    elements[-1][2].append((words[-1], "list", words[2], words[3]))
                else:
                    if words[1] not in _PLY_TYPES:
                        raise CanopyStereoError(f"{path}: unknown PLY type {words[1]!r}")
                    elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
        if fmt not in ("binary_little_endian", "binary_big_endian", "ascii"):
            raise CanopyStereoError(f"{path}: unsupported PLY format {fmt!r}")
        vertex = None
        for name, count, props in elements:
            if any(p[1] == "list" for p in props):
                if name == "vertex":
                    raise CanopyStereoError(f"{path}: list properties on vertices are not supported")
                break  # faces etc. come after vertices; not needed
            if fmt == "ascii":
                rows = [f.readline().split() for _ in range(count)]
                arr = np.array(rows, dtype=np.float64).reshape(count, len(props))
                data = {p[0]: arr[:, i].astype(p[1]) for i, p in enumerate(props)}
            else:
                endian = "<" if fmt == "binary_little_endian" else ">"
                dt = np.dtype([(p[0], endian + p[1]) for p in props])
                buf = f.read(dt.itemsize * count)
                if len(buf) < dt.itemsize * count:
                    raise CanopyStereoError(f"{path}: truncated PLY ({name} data ends early)")
                rec = np.frombuffer(buf, dtype=dt)
                data = {p[0]: rec[p[0]] for p in props}
            if name == "vertex":
                vertex = data
                break
    if vertex is None or not all(k in vertex for k in "xyz"):
        raise CanopyStereoError(f"{path}: PLY has no vertex element with x, y, z")
    pts = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1).astype(np.float64)
    cols = None
    if all(k in vertex for k in ("red", "green", "blue")):
        cols = np.stack([vertex["red"], vertex["green"], vertex["blue"]], axis=1).astype(np.uint8)
    extra = {k: np.asarray(v) for k, v in vertex.items() if k not in ("x", "y", "z", "red", "green", "blue")}
    return PointCloud(points=pts, colors=cols, unit=unit, extra={"comments": comments, **extra})
