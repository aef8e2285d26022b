"""``segment_node``: GrabCut plant/background segmentation of the rectified left image.

Subscribes ``left/image_rect_color`` (bgr8) and, with ``depth_cue``, ``disparity``
(``stereo_msgs/DisparityImage`` on the same rectified grid, paired by exact stamp), and
publishes ``left/mask`` (mono8, 255 = plant, 0 = background) with the image's stamp and
frame.

The computation is the package's one plant seeder,
:func:`canopy_stereo.segmentation.plant_mask` (full cuts; propagated between them by
:class:`~canopy_stereo.segmentation.propagate.MaskPropagator`), with the node's preset
:data:`~canopy_stereo.segmentation.VIDEO_SEEDER` (saturation, a quarter of the
resolution). Its settings (:class:`~canopy_stereo.segmentation.SeederSettings`) are the
node's parameters, with their ranges (changeable at run time unless noted):

* ``rect``: ``[x, y, width, height]`` initial rectangle in rectified pixels (the
  paper's interaction: the plant lies inside it); ``[]``/zero size = automatic;
* ``auto_init`` (the settings' ``colour_cue``): automatic initialisation when no
  rectangle is given, from an index thresholded by Otsu's method: ``saturation``
  (colourful plant in front of a neutral backdrop, as in the laboratory scenes;
  default), ``exg`` (excess-green vegetation index, for green canopies against soil or
  sky), ``exgr``, ``exr``, ``border`` (everything but a 5 % frame is probably plant) or
  ``none`` (the depth cue alone; needs ``depth_cue``);
* ``depth_cue`` (read-only, default false): also subscribe ``disparity`` and use it as
  the CLI does (near = plant; the colour threshold is found among the near pixels);
  a mask then waits for the disparity of its image;
* ``follow_disparity`` (read-only, default false; the launch file and ``canopy_graph`` set it
  when the cloud is masked): segment only the images ``disparity_node`` matched: subscribe
  ``disparity`` and pair it with its image by exact stamp (as ``depth_cue`` does, without using
  its values). When the cameras outpace the matcher, the frames it skips get no cloud, and now
  no mask either: the segmentation's CPU goes to the frames that become clouds (a mask then
  comes after its disparity: the cloud's latency grows by the segmentation time, about
  4 ms of CPU at 640x480 plus receiving and publishing). Images wait up to ``FOLLOW_QUEUE`` frames for their disparity;
* ``sure_margin``, ``edge_px``, ``colour_model``, ``refine``, ``min_region``: see
  :class:`~canopy_stereo.segmentation.SeederSettings` (-1 / ``auto`` = its None);
* ``iterations``: GrabCut iterations;
* ``scale``: the image is segmented at this scale (GrabCut is costly) and the
  mask resized back;
* ``recut_every`` (default 10): a full GrabCut every this many frames; the frames
  between reuse the plant and background colour models of the last full cut with the
  frame's own seed, one graph cut at ``propagate_scale``
  (:class:`canopy_stereo.segmentation.propagate.MaskPropagator`: about a third of the
  CPU, within IoU 0.95 of full cuts on the bundled scenes); 1 = a full cut every frame;
* ``propagate_scale`` (default 0 = ``scale``): processing scale of the propagated frames;
* ``max_pixels`` (default 19200, a 640x480 frame at scale 0.25): both scales are lowered for
  larger images so that GrabCut works on at most this many pixels (a 1280x720 frame at about
  184x104), the mask upsampled to the image (:func:`~canopy_stereo.segmentation.propagate.capped_scale`);
  0 = no cap;
* ``queue_size`` (read-only): input queue depth; 1 makes the node segment the
  newest image and skip those that arrived while it was busy (used when no
  point cloud waits for the masks);
* ``image_width``, ``image_height`` (read-only, 0 = any): the size every image must
  have -- the rig file's, so ``--params-file RIG.yaml`` sets them; other sizes are
  dropped before decoding. Without them only the hard limits of
  :mod:`canopy_stereo.ros.limits` apply.

A change of any seeder parameter, ``rect``, ``max_pixels`` or the propagation parameters starts again
with a full cut.
"""
from __future__ import annotations

import numpy as np
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Image
from stereo_msgs.msg import DisparityImage

from canopy_stereo.bag.pairing import ExactTimeSynchronizer
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.ros.cdr_views import disparity_view, image_view
from canopy_stereo.ros.convert import (
    COLOUR_ENCODINGS,
    disparity_to_msg,
    image_to_msg,
    msg_to_bgr,
    msg_to_disparity,
    stamp_to_ns,
)
from canopy_stereo.ros.limits import SEGMENT_MIN_SIZE, check_disparity_msg, check_image_msg
from canopy_stereo.ros.nodes.base import WARM_UP_SIZE, CanopyNode, run_node
from canopy_stereo.segmentation.auto import VIDEO_SEEDER, decode_setting, seeder_fields
from canopy_stereo.segmentation.grabcut import clip_rect, compile_cut_kernels
from canopy_stereo.segmentation.propagate import DEFAULT_MAX_PIXELS, DEFAULT_RECUT_EVERY, MaskPropagator

#: Streams of the exact-time pairing with ``depth_cue`` or ``follow_disparity``.
_STREAMS = ("left/image_rect_color", "disparity")
#: Images kept waiting for their disparity with ``follow_disparity`` (1 s at 30 frames/s: the
#: matcher's latency under load, 0.5 s at 1280x720 on two cores).
FOLLOW_QUEUE = 30


class SegmentNode(CanopyNode):
    """GrabCut on every rectified left colour image (see module docstring)."""

    def __init__(self, node_name: str = "segment_node", **kwargs):
        super().__init__(node_name, **kwargs)
        self.declare_parameter("rect", [0, 0, 0, 0], ParameterDescriptor(
            description="initial rectangle [x, y, width, height] in rectified pixels; "
                        "zero size = automatic initialisation", dynamic_typing=True))
        self.seeder_fields = seeder_fields(VIDEO_SEEDER)
        for f in self.seeder_fields:
            if f["kind"] == "number":
                self.declare_number(f["name"], f["default"], f["description"], minimum=f["minimum"],
                                    maximum=f["maximum"])
            elif f["kind"] == "text":
                self.declare_text(f["name"], f["default"], f["description"], choices=f["choices"])
            else:
                self.declare_flag(f["name"], f["default"], f["description"],
                                  read_only=f["field"] == "depth_cue")
        self.declare_number("recut_every", DEFAULT_RECUT_EVERY, "a full GrabCut every this many frames; "
                            "the frames between reuse its colour models (one graph cut); 1 = every frame",
                            minimum=1, maximum=10000)
        self.declare_number("propagate_scale", 0.0, "processing scale of the frames between full cuts "
                            "(0 = scale)", minimum=0.0, maximum=1.0)
        self.declare_number("max_pixels", DEFAULT_MAX_PIXELS, "GrabCut works on at most this many pixels: "
                            "scale and propagate_scale are lowered for larger images (0 = no cap)",
                            minimum=0, maximum=100_000_000)
        self.declare_number("queue_size", 5, "input queue depth; 1 = always segment the latest image "
                            "and skip the ones that arrived meanwhile (when nothing waits for every mask)",
                            minimum=1, maximum=100, read_only=True)
        self.declare_flag("follow_disparity", False, "segment only the images disparity_node matched (pair "
                          "each image with its disparity by exact stamp): no mask for a frame that gets no "
                          "cloud", read_only=True)
        self.declare_number("image_width", 0, "width every image must have (the rig's); 0 = any",
                            minimum=0, maximum=16384, read_only=True)
        self.declare_number("image_height", 0, "height every image must have (the rig's); 0 = any",
                            minimum=0, maximum=16384, read_only=True)
        size = (int(self.get_parameter("image_width").value), int(self.get_parameter("image_height").value))
        self.expected_size = size if min(size) > 0 else None
        self.image_size_seen = None  # (width, height) of the latest image: new rects are checked against it
        self.settings = self._settings({})
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.pub = self.make_publisher(Image, "left/mask")
        depth = max(1, int(self.get_parameter("queue_size").value))
        self.depth_cue = bool(self.settings["seeder"].depth_cue)
        self.follow_disparity = bool(self.get_parameter("follow_disparity").value)
        self.sync = None
        if self.depth_cue or self.follow_disparity:
            waiting = max(depth, FOLLOW_QUEUE if self.follow_disparity else 5)
            self.sync = ExactTimeSynchronizer(2, waiting, on_jump=self.time_jump_handler(_STREAMS))
            self.sub_disp = self.make_subscription(DisparityImage, "disparity", lambda m: self._on(1, m),
                                                   depth=depth, parse=disparity_view)
        w, h = self.expected_size or WARM_UP_SIZE
        self.warm_up(f"segmentation of {w}x{h} images", self._warm_up)
        # both inputs are read in place from the serialized messages (cdr_views: no deserialisation)
        self.sub = self.make_subscription(Image, "left/image_rect_color", lambda m: self._on(0, m),
                                          depth=depth, parse=image_view)

    def _warm_up(self) -> None:
        """A full cut and a propagated frame on a synthetic image of the rig's size, with a
        propagator of its own (the node's starts fresh), nothing published."""
        from canopy_stereo.sim.stereo_pair import synthetic_pair

        w, h = self.expected_size or WARM_UP_SIZE
        left, _, disparity = synthetic_pair(w, h, plane=(0.0, 0.0, 20.0), texture="blocks", colour=True)
        wire = disparity_to_msg(disparity, 500.0, 0.1, 0.0, 64.0)
        # as messages (an intra-process bus) and as views of serialized ones (read-only arrays)
        for image, disparity_msg in ((left, wire), (msg_to_bgr(image_view(serialize_message(image_to_msg(left)))),
                                                    disparity_view(serialize_message(wire)))):
            check_disparity_msg(disparity_msg)  # the limits' and the wire conversion's kernels
            frame = msg_to_disparity(disparity_msg)
            propagator = self._settings({})["propagator"]
            for _ in range(2):
                mask = propagator.segment(image, disparity=frame.disparity if self.depth_cue else None)
        image_to_msg(mask, "mono8", stamp_ns=1, frame_id="")
        compile_cut_kernels()  # the compiled GrabCut the synthetic frame's seed did not reach

    def _settings(self, changes: dict) -> dict:
        """``{"rect": (x, y, w, h) or None, "seeder": SeederSettings}`` of the parameters with
        ``changes``; raises :class:`CanopyStereoError` on a bad combination."""
        def value(name):
            return changes[name] if name in changes else self.get_parameter(name).value

        rect = value("rect")
        rect = [int(v) for v in rect] if rect is not None and len(rect) else [0, 0, 0, 0]
        if len(rect) != 4:
            raise CanopyStereoError(f"rect must be [x, y, width, height], got {rect}")
        seeder = VIDEO_SEEDER.replace(**{f["field"]: decode_setting(f["field"], value(f["name"]))
                                         for f in self.seeder_fields})
        if not seeder.depth_cue and seeder.colour_cue == "none":
            raise CanopyStereoError("auto_init none needs depth_cue (a disparity to seed from)")
        if not seeder.depth_cue and seeder.colour_model:
            raise CanopyStereoError("colour_model on needs depth_cue (it learns from the disparity)")
        rect = tuple(rect) if rect[2] > 0 and rect[3] > 0 else None
        size = self.expected_size or self.image_size_seen
        if rect is not None and size is not None:  # an image size is known: the rectangle must fit it
            clip_rect(rect, size)
        recut_every, propagate_scale = int(value("recut_every")), float(value("propagate_scale"))
        return {"rect": rect, "seeder": seeder, "recut_every": recut_every, "propagate_scale": propagate_scale,
                "propagator": MaskPropagator(settings=seeder, rect=rect, recut_every=recut_every,
                                             propagate_scale=propagate_scale or seeder.scale,
                                             max_pixels=int(value("max_pixels"))),
                # the settings as they were named before SeederSettings, for readers of the node
                "iterations": seeder.iterations, "auto_init": seeder.colour_cue, "scale": seeder.scale}

    def _on_set_parameters(self, parameters) -> SetParametersResult:
        try:
            settings = self._settings({p.name: p.value for p in parameters})
        except (CanopyStereoError, TypeError, ValueError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        self.settings = settings
        return SetParametersResult(successful=True)

    def _on(self, stream: int, msg) -> None:
        if stream == 0:
            self.count("received")
            check_image_msg(msg, expected_size=self.expected_size, encodings=COLOUR_ENCODINGS,
                            min_size=SEGMENT_MIN_SIZE)
            item = msg_to_bgr(msg)
            self.image_size_seen = (item.shape[1], item.shape[0])
            rect = self.settings["rect"]
            if rect is not None:
                try:
                    clip_rect(rect, self.image_size_seen)
                except CanopyStereoError as exc:
                    raise CanopyStereoError(f"parameter rect {list(rect)} does not fit the images: {exc}; "
                                            "set rect within them, or [0, 0, 0, 0] (automatic)") from None
        else:
            self.count("disparity_received")
            # follow_disparity alone reads the stamp (and the size) only: no pixel scan
            check_disparity_msg(msg, expected_size=self.expected_size, pixels=self.depth_cue)
            if self.depth_cue:
                frame = msg_to_disparity(msg)
                # message disparities are reduced by the cameras' cx offset: measured from the
                # search range's start they are >= 0 where valid, near = high (NaN = unknown)
                item = frame.disparity - np.float32(frame.min_disparity)
            else:  # follow_disparity: its stamp says which image to segment
                item = None
        if self.sync is None:
            self._segment(msg.header, item, None)
            return
        items, dropped = self.sync.push(stream, stamp_to_ns(msg.header.stamp), (msg.header, item))
        self.drop_unpaired(dropped, _STREAMS)
        if items is not None:
            (header, bgr), (_, disparity) = items
            self._segment(header, bgr, disparity)

    def _segment(self, header, bgr, disparity) -> None:
        """Publish the mask of ``bgr`` (with the disparity cue when given) under ``header``."""
        s = self.settings
        if disparity is not None and disparity.shape != bgr.shape[:2]:
            raise CanopyStereoError(f"disparity is {disparity.shape[1]}x{disparity.shape[0]} but the "
                                    f"image is {bgr.shape[1]}x{bgr.shape[0]}")
        propagator = s["propagator"]
        full_cuts = propagator.full_cuts
        mask = propagator.segment(bgr, disparity=disparity)
        self.diagnostics.sample("full cut share", float(propagator.full_cuts > full_cuts))
        self.pub.publish(image_to_msg(mask, "mono8", stamp_ns=stamp_to_ns(header.stamp),
                                      frame_id=header.frame_id))
        self.count("masks_published")


def main(args=None) -> int:
    """``ros2 run canopy_stereo segment_node``."""
    return run_node(SegmentNode, args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
