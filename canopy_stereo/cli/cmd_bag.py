"""``canopy-stereo bag``: check a bag's integrity, repair it into a complete copy, or compress its images."""
from __future__ import annotations

from pathlib import Path

from canopy_stereo.errors import CanopyStereoError

COMMAND = "bag"
HELP = ("check a rosbag2 MCAP bag's integrity (check), copy everything intact (repair), or store its "
        "images compressed (compress)")
DESCRIPTION = """check FILE: read every chunk of the bag (CRC, size, records), the summary and the
data-section CRC; print its integrity, topics, message counts, every damaged place (byte offset,
problem, messages lost) and what is recoverable. Exit 0 when the bag is complete and intact,
1 when it is damaged or was never closed (cut short), 2 when it cannot be read at all.
repair FILE -o OUT: write every message that reads intact to OUT, a complete bag (summary,
indexes, footer) that rosbags, mcap and ros2 bag read; then print the check of FILE.
compress FILE -o OUT [--jpeg-quality Q]: copy the bag with every 8-bit image topic stored as
image_transport's <topic>/compressed (sensor_msgs/CompressedImage: JPEG at Q, default 95; PNG
for masks; other images stay raw), as robot bags hold them."""


def add_arguments(p):
    sub = p.add_subparsers(dest="bag_command", metavar="ACTION")
    sub.required = True
    check = sub.add_parser("check", help="report integrity, topics, counts and what is recoverable",
                           description="Read the whole bag and report its integrity.")
    check.add_argument("file", metavar="FILE", help="bag (.mcap)")
    repair = sub.add_parser("repair", help="write a complete copy of everything intact",
                            description="Copy every intact message of FILE into a new complete bag OUT.")
    repair.add_argument("file", metavar="FILE", help="damaged or unclosed bag (.mcap)")
    repair.add_argument("-o", "--output", required=True, metavar="OUT", help="repaired bag (.mcap)")
    repair.add_argument("--compression", choices=("zstd", "lz4", "none"), default=None,
                        help="chunk compression of OUT (default: that of FILE)")
    repair.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    comp = sub.add_parser("compress", help="copy with the images compressed (<topic>/compressed)",
                          description="Copy FILE to OUT with its 8-bit images as CompressedImage.")
    comp.add_argument("file", metavar="FILE", help="bag (.mcap)")
    comp.add_argument("-o", "--output", required=True, metavar="OUT", help="compressed bag (.mcap)")
    comp.add_argument("--jpeg-quality", type=int, default=95, metavar="Q", help="JPEG quality 1-100 (default 95)")
    comp.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")


def run(args) -> int:
    from canopy_stereo.bag import BagReader, repair_bag

    if args.bag_command == "check":
        check = BagReader(args.file).verify()
        for line in check.lines():
            print(line)
        return 0 if check.ok else 1
    out = Path(args.output)
    if out.exists() and not args.overwrite:
        raise CanopyStereoError(f"{out} exists (choose another name or pass --overwrite)")
    if args.bag_command == "compress":
        from canopy_stereo.ros import require_ros

        require_ros("canopy-stereo bag compress")
        from canopy_stereo.ros.bag_images import compress_bag

        counts = compress_bag(args.file, out, quality=args.jpeg_quality, overwrite=args.overwrite)
        for topic, n in sorted(counts.items()):
            print(f"{topic}: {n}")
        print(f"compressed: {out} ({Path(args.file).stat().st_size} -> {out.stat().st_size} bytes)")
        return 0
    check = repair_bag(args.file, out, compression=args.compression, overwrite=args.overwrite)
    written = BagReader(out).verify()
    if not written.ok:  # never claim a repair that did not produce a clean file
        raise CanopyStereoError(f"{out}: the repaired copy does not verify: "
                                + (written.damage[0].problem if written.damage else "incomplete"))
    for line in check.lines():
        print(line)
    total = sum(written.messages_recovered.values())
    print(f"repaired: {out} ({total} messages, complete)")
    return 0
