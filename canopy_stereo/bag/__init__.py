"""rosbag2-compatible MCAP bags without rclpy: write, read with checks, repair, pair by time.

Pure Python (``mcap``, ``yaml``); rclpy is imported only to serialize a ROS message
object or decode one (:meth:`BagMessage.decode`), so batch runs, the pipeline and the
CLI read and write bags without a ROS installation. One job per module:

* :mod:`~canopy_stereo.bag.writer`: :class:`BagWriter` (chunked, CRC'd, fsynced every
  second, split files; safe against Ctrl-C/SIGTERM via :mod:`~canopy_stereo.bag.interrupts`).
* :mod:`~canopy_stereo.bag.reader`: :class:`BagReader`, which never returns damaged data;
  the MCAP record framing it parses: :mod:`~canopy_stereo.bag.mcap_records`; what a full
  check finds: :mod:`~canopy_stereo.bag.check` (:class:`BagDamage`, :class:`BagCheck`).
* :mod:`~canopy_stereo.bag.repair`: :func:`repair_bag` (every intact message into a complete bag).
* :mod:`~canopy_stereo.bag.messages`: :class:`BagMessage`, :class:`TopicInfo`, QoS metadata.
* :mod:`~canopy_stereo.bag.msgdefs`: message type names and ``ros2msg`` schema text.
* :mod:`~canopy_stereo.bag.metadata`: canopy_stereo's metadata records (recording
  key/values and the rig).
* :mod:`~canopy_stereo.bag.split`: split-file names and the ``--split-*`` options.
* :mod:`~canopy_stereo.bag.pairing`: exact and approximate time pairing of message streams.
* :mod:`~canopy_stereo.bag.errors`: :class:`BagError`.

Times are integer nanoseconds since the epoch.
"""
from canopy_stereo.bag.check import BagCheck, BagDamage
from canopy_stereo.bag.errors import BagError
from canopy_stereo.bag.messages import BagMessage, TopicInfo
from canopy_stereo.bag.reader import BagReader
from canopy_stereo.bag.repair import repair_bag
from canopy_stereo.bag.writer import BagWriter

__all__ = ["BagCheck", "BagDamage", "BagError", "BagMessage", "BagReader", "BagWriter",
           "TopicInfo", "repair_bag"]
