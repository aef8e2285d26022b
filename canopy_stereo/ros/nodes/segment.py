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
* ``recut_every`` (default 10): a full GrabCut every this many frames; the frames
  between reuse the plant and background colour models of the last full cut with the
  frame's own seed, one graph cut at ``propagate_scale``
  (:class:`canopy_stereo.segmentation.propagate.MaskPropagator`: about a third of the
  CPU, within IoU 0.95 of full cuts on the bundled scenes); 1 = a full cut every frame;
* ``propagate_scale`` (default 0 = ``scale``): processing scale of the propagated frames;
* ``queue_size`` (read-only): input queue depth; 1 makes the node segment the
  newest image and skip those that arrived while it was busy (used when no
  point cloud waits for the masks);
* ``image_width``, ``image_height`` (read-only, 0 = any): the size every image must
  have -- the rig file's, so ``--params-file RIG.yaml`` sets them; other sizes are
  dropped before decoding. Without them only the hard limits of
  :mod:`canopy_stereo.ros.limits` apply.

The computation itself is
:func:`canopy_stereo.segmentation.video.segment_plant` (full cuts), propagated by
:class:`canopy_stereo.segmentation.propagate.MaskPropagator`. A change of ``rect``,
``iterations``, ``auto_init``, ``scale`` or the propagation parameters starts again with a
full cut.
"""
from __future__ import annotations

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from sensor_msgs.msg import Image

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.ros.convert import COLOUR_ENCODINGS, image_to_msg, msg_to_bgr, stamp_to_ns
from canopy_stereo.ros.limits import SEGMENT_MIN_SIZE, check_image_msg
from canopy_stereo.ros.nodes.base import CanopyNode, run_node
from canopy_stereo.segmentation.propagate import DEFAULT_RECUT_EVERY, MaskPropagator
from canopy_stereo.segmentation.video import AUTO_INITS

class SegmentNode(CanopyNode):
    """GrabCut on every rectified left colour image (see module docstring)."""

    def __init__(self, node_name: str = "segment_node", **kwargs):
        super().__init__(node_name, **kwargs)
        self.declare_parameter("rect", [0, 0, 0, 0], ParameterDescriptor(
            description="initial rectangle [x, y, width, height] in rectified pixels; "
                        "zero size = automatic initialisation", dynamic_typing=True))
        self.declare_number("iterations", 3, "GrabCut iterations", minimum=1, maximum=100)
        self.declare_text("auto_init", "saturation", "automatic initialisation when rect is empty",
                          choices=AUTO_INITS)
        self.declare_number("scale", 0.25, "processing scale: images are segmented at this fraction "
                            "of their size and the mask resized back", minimum=0.01, maximum=1.0)
        self.declare_number("recut_every", DEFAULT_RECUT_EVERY, "a full GrabCut every this many frames; "
                            "the frames between reuse its colour models (one graph cut); 1 = every frame",
                            minimum=1, maximum=10000)
        self.declare_number("propagate_scale", 0.0, "processing scale of the frames between full cuts "
                            "(0 = scale)", minimum=0.0, maximum=1.0)
        self.declare_number("queue_size", 5, "input queue depth; 1 = always segment the latest image "
                            "and skip the ones that arrived meanwhile (when nothing waits for every mask)",
                            minimum=1, maximum=100, read_only=True)
        self.declare_number("image_width", 0, "width every image must have (the rig's); 0 = any",
                            minimum=0, maximum=16384, read_only=True)
        self.declare_number("image_height", 0, "height every image must have (the rig's); 0 = any",
                            minimum=0, maximum=16384, read_only=True)
        size = (int(self.get_parameter("image_width").value), int(self.get_parameter("image_height").value))
        self.expected_size = size if min(size) > 0 else None
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
                    "scale": float(value("scale")), "recut_every": int(value("recut_every")),
                    "propagate_scale": float(value("propagate_scale"))}
        if settings["iterations"] < 1:
            raise CanopyStereoError("iterations must be >= 1")
        if settings["auto_init"] not in AUTO_INITS:
            raise CanopyStereoError(f"auto_init must be one of {', '.join(AUTO_INITS)}")
        if not 0 < settings["scale"] <= 1:
            raise CanopyStereoError("scale must be in (0, 1]")
        settings["propagator"] = MaskPropagator(
            rect=settings["rect"], iterations=settings["iterations"], auto_init=settings["auto_init"],
            scale=settings["scale"], recut_every=settings["recut_every"],
            propagate_scale=settings["propagate_scale"] or settings["scale"])
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
        check_image_msg(msg, expected_size=self.expected_size, encodings=COLOUR_ENCODINGS, min_size=SEGMENT_MIN_SIZE)
        bgr = msg_to_bgr(msg)
        propagator = self.settings["propagator"]
        full_cuts = propagator.full_cuts
        mask = propagator.segment(bgr)
        self.diagnostics.sample("full cut share", float(propagator.full_cuts > full_cuts))
        self.pub.publish(image_to_msg(mask, "mono8", stamp_to_ns(msg.header.stamp), msg.header.frame_id))
        self.count("masks_published")


def main(args=None) -> int:
    """``ros2 run canopy_stereo segment_node``."""
    return run_node(SegmentNode, args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
