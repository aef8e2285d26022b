"""``segment_node``: GrabCut plant/background segmentation of the rectified left image.

Subscribes ``left/image_rect_color`` (bgr8) and publishes ``left/mask`` (mono8,
255 = plant, 0 = background) with the image's stamp and frame.

Parameters (changeable at run time):

* ``rect``: ``[x, y, width, height]`` initial rectangle in rectified pixels (the
  paper's interaction: the plant lies inside it); ``[]``/zero size = automatic;
* ``iterations``: GrabCut iterations;
* ``auto_init``: automatic initialisation when no rectangle is given, from an
  index thresholded by Otsu's method: ``saturation`` (colourful plant in front
  of a neutral backdrop, as in the laboratory scenes; default), ``exg``
  (excess-green vegetation index, for green canopies against soil or sky), or
  ``border`` (everything but a 5 % frame is probably plant);
* ``scale``: the image is segmented at this scale (GrabCut is costly) and the
  mask resized back;
* ``queue_size`` (read-only): input queue depth; 1 makes the node segment the
  newest image and skip those that arrived while it was busy (used when no
  point cloud waits for the masks).

The computation itself is :func:`segment_plant`.
"""
from __future__ import annotations

import cv2
import numpy as np
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from sensor_msgs.msg import Image

from canopy_stereo.errors import CanopyStereoError, ImageError
from canopy_stereo.ros.convert import image_to_msg, msg_to_bgr, stamp_to_ns
from canopy_stereo.ros.nodes.base import CanopyNode, run_node

AUTO_INITS = ("saturation", "exg", "border")


def excess_green(bgr: np.ndarray) -> np.ndarray:
    """Excess-green index ``2g - r - b`` of chromaticities (float32 (H, W), in [-1, 2])."""
    f = bgr.astype(np.float32)
    s = f.sum(axis=2) + 1e-6
    b, g, r = f[..., 0] / s, f[..., 1] / s, f[..., 2] / s
    return 2 * g - r - b


def _initial_labels(bgr, rect, auto_init: str) -> tuple[np.ndarray, int]:
    """GrabCut label image and mode for a rectangle or an automatic initialisation."""
    h, w = bgr.shape[:2]
    labels = np.full((h, w), cv2.GC_BGD, np.uint8)
    if rect is not None:
        x, y, rw, rh = rect
        labels[y:y + rh, x:x + rw] = cv2.GC_PR_FGD
        return labels, cv2.GC_INIT_WITH_MASK
    if auto_init == "border":
        mx, my = max(1, w // 20), max(1, h // 20)
        labels[my:h - my, mx:w - mx] = cv2.GC_PR_FGD
        return labels, cv2.GC_INIT_WITH_MASK
    if auto_init == "saturation":
        index8 = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)[..., 1]
    else:
        index8 = np.clip((excess_green(bgr) + 1.0) * (255.0 / 3.0), 0, 255).astype(np.uint8)
    thr, _ = cv2.threshold(index8, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    margin = 12  # index units around Otsu's threshold left to GrabCut to decide
    labels[index8 >= thr - margin] = cv2.GC_PR_BGD
    labels[index8 >= thr] = cv2.GC_PR_FGD
    labels[index8 >= thr + margin] = cv2.GC_FGD
    return labels, cv2.GC_INIT_WITH_MASK


def segment_plant(bgr: np.ndarray, rect=None, iterations: int = 3, auto_init: str = "saturation",
                  scale: float = 0.25) -> np.ndarray:
    """Plant mask of a BGR image by GrabCut: uint8 (H, W), 255 = plant.

    Args:
        bgr: uint8 (H, W, 3) image.
        rect: ``(x, y, width, height)`` rectangle containing the plant (pixels of
            ``bgr``), or None for the automatic initialisation.
        iterations: GrabCut iterations (>= 1).
        auto_init: ``"saturation"``, ``"exg"`` or ``"border"`` (see the module docstring).
        scale: processing scale in (0, 1].
    """
    if bgr.ndim != 3 or bgr.shape[2] != 3 or bgr.dtype != np.uint8:
        raise ImageError(f"segmentation needs a uint8 BGR image, got {bgr.dtype} {bgr.shape}")
    if not 0 < scale <= 1:
        raise CanopyStereoError(f"scale must be in (0, 1], got {scale}")
    if iterations < 1:
        raise CanopyStereoError(f"iterations must be >= 1, got {iterations}")
    if auto_init not in AUTO_INITS:
        raise CanopyStereoError(f"auto_init must be one of {', '.join(AUTO_INITS)}, got {auto_init!r}")
    h, w = bgr.shape[:2]
    small = bgr if scale == 1 else cv2.resize(bgr, (max(8, round(w * scale)), max(8, round(h * scale))),
                                              interpolation=cv2.INTER_AREA)
    sh, sw = small.shape[:2]
    srect = None
    if rect is not None:
        x, y, rw, rh = (int(v) for v in rect)
        x0, y0 = max(0, x), max(0, y)
        x1, y1 = min(w, x + rw), min(h, y + rh)
        if x1 - x0 < 2 or y1 - y0 < 2:
            raise CanopyStereoError(f"rectangle {list(rect)} does not overlap the {w}x{h} image")
        fx, fy = sw / w, sh / h
        srect = (int(x0 * fx), int(y0 * fy), max(2, int((x1 - x0) * fx)), max(2, int((y1 - y0) * fy)))
    labels, mode = _initial_labels(small, srect, auto_init)
    if not np.any((labels == cv2.GC_FGD) | (labels == cv2.GC_PR_FGD)):
        return np.zeros((h, w), np.uint8)
    if not np.any((labels == cv2.GC_BGD) | (labels == cv2.GC_PR_BGD)):
        return np.full((h, w), 255, np.uint8)
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    cv2.grabCut(small, labels, None, bgd, fgd, int(iterations), mode)
    mask = np.where((labels == cv2.GC_FGD) | (labels == cv2.GC_PR_FGD), 255, 0).astype(np.uint8)
    if mask.shape != (h, w):
        mask = cv2.resize(mask, (w, h), interpolation=cv2.INTER_LINEAR)
        mask = np.where(mask >= 128, 255, 0).astype(np.uint8)
    return mask


class SegmentNode(CanopyNode):
    """GrabCut on every rectified left colour image (see module docstring)."""

    def __init__(self, node_name: str = "segment_node", **kwargs):
        super().__init__(node_name, **kwargs)
        self.declare_parameter("rect", [0, 0, 0, 0], ParameterDescriptor(
            description="initial rectangle [x, y, width, height] in rectified pixels; "
                        "zero size = automatic initialisation", dynamic_typing=True))
        self.declare_parameter("iterations", 3, ParameterDescriptor(description="GrabCut iterations"))
        self.declare_parameter("auto_init", "saturation", ParameterDescriptor(
            description=f"automatic initialisation: {' or '.join(AUTO_INITS)}"))
        self.declare_parameter("scale", 0.25, ParameterDescriptor(
            description="processing scale in (0, 1]"))
        self.declare_parameter("queue_size", 5, ParameterDescriptor(
            description="input queue depth; 1 = always segment the latest image and skip the "
                        "ones that arrived meanwhile (when nothing waits for every mask)",
            read_only=True))
        self.settings = self._settings({})
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.pub = self.make_publisher(Image, "left/mask")
        self.sub = self.make_subscription(Image, "left/image_rect_color", self._on_image,
                                          depth=max(1, int(self.get_parameter("queue_size").value)))

    def _settings(self, changes: dict) -> dict:
        def value(name):
            return changes[name] if name in changes else self.get_parameter(name).value

        rect = value("rect")
        rect = [int(v) for v in rect] if rect is not None and len(rect) else [0, 0, 0, 0]
        if len(rect) != 4:
            raise CanopyStereoError(f"rect must be [x, y, width, height], got {rect}")
        settings = {"rect": tuple(rect) if rect[2] > 0 and rect[3] > 0 else None,
                    "iterations": int(value("iterations")), "auto_init": str(value("auto_init")),
                    "scale": float(value("scale"))}
        if settings["iterations"] < 1:
            raise CanopyStereoError("iterations must be >= 1")
        if settings["auto_init"] not in AUTO_INITS:
            raise CanopyStereoError(f"auto_init must be one of {', '.join(AUTO_INITS)}")
        if not 0 < settings["scale"] <= 1:
            raise CanopyStereoError("scale must be in (0, 1]")
        return settings

    def _on_set_parameters(self, parameters) -> SetParametersResult:
        try:
            settings = self._settings({p.name: p.value for p in parameters})
        except (CanopyStereoError, TypeError, ValueError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        self.settings = settings
        return SetParametersResult(successful=True)

    def _on_image(self, msg: Image) -> None:
        self.count("received")
        bgr = msg_to_bgr(msg)
        s = self.settings
        mask = segment_plant(bgr, s["rect"], s["iterations"], s["auto_init"], s["scale"])
        self.pub.publish(image_to_msg(mask, "mono8", stamp_to_ns(msg.header.stamp), msg.header.frame_id))
        self.count("masks_published")


def main(args=None) -> int:
    """``ros2 run canopy_stereo segment_node``."""
    return run_node(SegmentNode, args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
