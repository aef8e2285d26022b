"""Bag playback (``bag_play``): publish a bag's messages with their recorded timing.

Messages are published as the CDR bytes stored in the bag (no
deserialization). Timing follows the log times: message ``i`` goes out at
``start + (t_i - t_first) / rate``; ``rate = 0`` publishes as fast as the
``before_publish`` hook allows (flow control, used by ``canopy-stereo run``).
Options: ``loop``, ``start_offset`` (seconds into the bag), topic remapping and
a topic filter.

``bag_play BAG.mcap [--rate R] [--loop] [--start-offset S] [--remap FROM:=TO ...]
[--topics T ...] [--delay S]`` plays from the command line.
"""
from __future__ import annotations

import argparse
import sys
import threading
import time
from dataclasses import dataclass, field

import yaml

from canopy_stereo.bag import BagError, BagMessage, BagReader
from canopy_stereo.bag.msgdefs import message_class
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.ros.qos import publisher_qos


def parse_remaps(items) -> dict:
    """``["/a:=/b", ...]`` -> ``{"/a": "/b"}`` (raises :class:`CanopyStereoError`)."""
    out = {}
    for item in items or ():
        if ":=" not in item:
            raise CanopyStereoError(f"remap {item!r} must look like /from:=/to")
        src, dst = (s.strip() for s in item.split(":=", 1))
        if not src or not dst:
            raise CanopyStereoError(f"remap {item!r} must look like /from:=/to")
        out[src] = dst
    return out


def recorded_reliability(qos_yaml: str) -> str:
    """``reliable`` or ``best_effort`` from a topic's ``offered_qos_profiles`` (default reliable)."""
    try:
        profiles = yaml.safe_load(qos_yaml) or []
        values = {str(p.get("reliability", "reliable")).lower() for p in profiles if isinstance(p, dict)}
    except yaml.YAMLError:
        return "reliable"
    return "best_effort" if values & {"best_effort", "2"} else "reliable"


@dataclass
class PlayStats:
    """What a playback did: messages published per topic, loops, wall time (s)."""

    published: dict = field(default_factory=dict)
    loops: int = 0
    wall_s: float = 0.0
    truncated: bool = False
    problem: str = ""

    @property
    def total(self) -> int:
        return sum(self.published.values())


class BagPlayer:
    """Publish the messages of a :class:`BagReader` from ``node``.

    Args:
        node: the rclpy node that owns the publishers.
        bag: the opened bag.
        rate: playback speed factor (1 = recorded timing, 0 = no waiting).
        loop: start again at the end until stopped.
        start_offset_s: skip the first seconds of the bag.
        remap: topic name -> published name.
        topics: topics to play (None: all).
        depth: publisher queue depth.
    """

    def __init__(self, node, bag: BagReader, rate: float = 1.0, loop: bool = False,
                 start_offset_s: float = 0.0, remap: dict | None = None, topics=None, depth: int = 1):
        if rate < 0:
            raise CanopyStereoError(f"rate must be >= 0, got {rate}")
        if start_offset_s < 0:
            raise CanopyStereoError(f"start offset must be >= 0 s, got {start_offset_s}")
        self.node, self.bag, self.rate, self.loop = node, bag, float(rate), bool(loop)
        self.start_offset_ns = int(round(start_offset_s * 1e9))
        self.remap = dict(remap or {})
        wanted = set(bag.topics) if topics is None else set(topics)
        unknown = sorted(wanted - set(bag.topics))
        if unknown:
            raise CanopyStereoError(f"topic(s) {', '.join(unknown)} not in {bag.path}; it has "
                                    f"{', '.join(sorted(bag.topics)) or 'none'}")
        if topics is None:  # all: leave out types not installed here (tf2_msgs without a ROS install)
            for topic in sorted(wanted):
                try:
                    message_class(bag.topics[topic].type_name)
                except CanopyStereoError as exc:
                    node.get_logger().warning(f"not playing {topic}: {exc}")
                    wanted.discard(topic)
        self.topics = sorted(wanted)
        self.publishers = {}
        for topic in self.topics:
            info = bag.topics[topic]
            qos = publisher_qos(recorded_reliability(info.qos_yaml), depth)
            if "transient_local" in info.qos_yaml:  # /tf_static: latched again, as recorded
                from rclpy.qos import DurabilityPolicy

                qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
            self.publishers[topic] = node.create_publisher(
                message_class(info.type_name), self.remap.get(topic, topic), qos)

    def wait_for_subscribers(self, timeout_s: float, topics=None) -> bool:
        """Wait until the publishers of ``topics`` (default all) have a subscriber."""
        from canopy_stereo.ros.context import wait_for_subscribers

        pubs = [self.publishers[t] for t in (topics or self.topics)]
        return wait_for_subscribers(pubs, timeout_s)

    def wait_until_delivered(self, timeout_s: float = 5.0) -> bool:
        """Wait until every reliable subscriber acknowledged all published messages
        (call before the process exits, or the last messages may never leave it)."""
        from rclpy.duration import Duration

        deadline = time.monotonic() + timeout_s
        ok = True
        for pub in self.publishers.values():
            left = max(0.0, deadline - time.monotonic())
            ok = pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))) and ok
        return ok

    def play(self, stop: threading.Event | None = None, before_publish=None,
             *, on_published=None, on_pass=None) -> PlayStats:
        """Publish until the end (or forever with ``loop``) or until ``stop`` is set.

        Args:
            stop: event that ends playback early.
            before_publish: ``f(BagMessage)`` called before each message (may block
                for flow control; returning False skips the message).
            on_published: ``f(BagMessage, wall_time_s)`` called after each message.
            on_pass: ``f(passes_done)`` called at the end of each complete pass of ``loop``.
        """
        stop = stop or threading.Event()
        stats = PlayStats(published={t: 0 for t in self.topics})
        t_start = time.monotonic()
        offset_wall = 0.0
        first_log = self.bag.start_ns + self.start_offset_ns
        span_s = max(0.0, (self.bag.end_ns - first_log) / 1e9)
        while not stop.is_set():
            for m in self.bag.messages(self.topics, start_ns=first_log):
                if stop.is_set():
                    break
                if self.rate > 0:
                    target = t_start + offset_wall + (m.log_time_ns - first_log) / 1e9 / self.rate
                    delay = target - time.monotonic()
                    if delay > 0 and stop.wait(delay):
                        break
                if before_publish is not None and before_publish(m) is False:
                    continue
                self.publishers[m.topic].publish(m.data)
                stats.published[m.topic] += 1
                if on_published is not None:
                    on_published(m, time.monotonic())
            stats.truncated, stats.problem = self.bag.truncated, self.bag.problem
            if not self.loop or stop.is_set():
                break
            stats.loops += 1
            if on_pass is not None:
                on_pass(stats.loops)
            # the next pass starts one mean message interval after the last message
            n = max(1, self.bag.message_count)
            offset_wall += (span_s + span_s / n) / self.rate if self.rate > 0 else 0.0
        stats.wall_s = time.monotonic() - t_start
        return stats


def add_playback_arguments(p: argparse.ArgumentParser, *, loop_help: str) -> None:
    """The playback options every bag-playing executable shares (``bag_play``, ``canopy_graph``):
    ``--rate`` (speed factor, 0 = as fast as possible) and ``--loop`` (described by ``loop_help``)."""
    p.add_argument("--rate", type=float, default=1.0, help="bag playback speed factor (0 = as fast as possible)")
    p.add_argument("--loop", action="store_true", help=loop_help)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="bag_play", description="Play a rosbag2 MCAP file.")
    p.add_argument("bag", help="bag file (.mcap)")
    add_playback_arguments(p, loop_help="play again from the start at the end")
    p.add_argument("--start-offset", type=float, default=0.0, metavar="S", help="skip the first S seconds")
    p.add_argument("--remap", nargs="*", default=[], metavar="FROM:=TO", help="rename topics")
    p.add_argument("--topics", nargs="*", default=None, metavar="TOPIC", help="play only these topics")
    p.add_argument("--delay", type=float, default=1.0, metavar="S",
                   help="wait up to S seconds for subscribers to connect before playing")
    p.add_argument("--queue", type=int, default=10, metavar="N", help="publisher queue depth (default 10)")
    return p


def main(args=None) -> int:
    """``bag_play`` executable."""
    import rclpy
    from rclpy.executors import ExternalShutdownException

    from canopy_stereo.ros.context import init_executable_ros, parse_executable_args
    from canopy_stereo.ros.nodes.base import install_stop_signals

    argv = sys.argv if args is None else args
    opts = parse_executable_args("bag_play", build_parser(), argv)
    if opts is None or not init_executable_ros("bag_play", argv):  # bad --ros-args: one line
        return 2
    install_stop_signals()
    node = None

    def damaged(d) -> None:  # each damaged place once, as it is found; the rest still plays
        print(f"bag_play: warning: {d.describe(opts.bag)}; skipped", file=sys.stderr, flush=True)

    try:
        bag = BagReader(opts.bag, on_damage=damaged)
        if bag.message_count == 0 and (bag.truncated or bag.damage):
            raise BagError(f"{bag.path}: nothing to play: {bag.problem}")
        if bag.truncated:
            print(f"bag_play: warning: {bag.path} is truncated ({bag.problem}); "
                  "playing the readable part", file=sys.stderr)
        node = rclpy.create_node("bag_player")
        player = BagPlayer(node, bag, opts.rate, opts.loop, opts.start_offset,
                           parse_remaps(opts.remap), opts.topics, depth=max(1, opts.queue))
        if player.wait_for_subscribers(max(0.0, opts.delay)):
            time.sleep(0.2)  # let the matched readers finish their handshake
        stats = player.play()
        player.wait_until_delivered(5.0)
        lost = (f"; {bag.messages_lost}{' or more' if bag.lost_unknown else ''} messages lost to "
                f"damage" if bag.damage else "")
        print(f"bag_play: published {stats.total} messages in {stats.wall_s:.2f} s{lost}")
        return 0
    except CanopyStereoError as exc:
        print(f"bag_play: error: {exc}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


__all__ = ["BagMessage", "BagPlayer", "PlayStats", "main", "parse_remaps"]


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
