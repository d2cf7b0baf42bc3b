"""``univtac-data export lerobot SRC DST [--fps N] [--video]``: a LeRobot v3.0 dataset from a univtac-data one."""

from __future__ import annotations

import argparse
from typing import Any


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "export", help="write a dataset in another ecosystem's format (lerobot: LeRobot v3.0)",
        description="Write the episodes of SRC as a LeRobot v3.0 dataset at DST (a new local folder): "
                    "meta/info.json, data/chunk-XXX/file-XXX.parquet, meta/episodes, meta/stats.json, "
                    "meta/tasks.parquet, and with --video the images as MP4. docs/export.md lists which field "
                    "becomes which LeRobot feature.",
        epilog="example: univtac-data export lerobot out/indenters out/indenters-lerobot --video",
    )
    parser.add_argument("target", choices=("lerobot",), help="format to write (lerobot: LeRobot dataset v3.0)")
    parser.add_argument("src", help="source dataset directory or fsspec URL")
    parser.add_argument("dst", help="new local folder to create")
    parser.add_argument("--fps", type=int, help="frame rate of the export; must divide the recorded rate "
                                                "(default: the recorded rate)")
    parser.add_argument("--video", action="store_true",
                        help="camera and tactile images as MP4 (H.264) files instead of PNG inside the Parquet "
                             "(needs the [video] extra)")
    return parser


def run(args: argparse.Namespace) -> int:
    from univtac_data.export.lerobot import export_lerobot, print_progress

    report = export_lerobot(args.src, args.dst, fps=args.fps, video=args.video, progress=print_progress)
    mode = "MP4 videos" if report.video else "PNG images in Parquet"
    print(f"exported {report.episodes} episodes ({report.frames} frames at {report.fps} fps, {mode}) as "
          f"LeRobot v3.0 to {report.dst}")
    return 0
