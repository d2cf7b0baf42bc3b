"""``univtac-data preview``: a contact sheet PNG of a dataset episode's tactile frames, or of a demo press.

    univtac-data preview PATH --out FILE.png [--episode ID] [--frames K] [--pad left|right]
    univtac-data preview PATH --gallery --out FILE.png [--max-episodes N]
    univtac-data preview --sensor gelsight_mini --demo sphere --out FILE.png [--method elastic] [--depth MM]
    univtac-data preview PATH --video OUT.mp4 [--rerun FILE.rrd] [--episode ID]
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any

import numpy as np

from univtac_data.schema.sensors import SENSORS, get_sensor
from univtac_data.storage import Dataset
from univtac_data.storage.errors import DatasetError
from univtac_data.cli.args import check_output_file, positive_int



def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "preview", help="write a contact sheet PNG (I_marked, I_pure, depth, marker motion) of a dataset "
        "episode, or of a demo indenter pressed into a sensor",
        description="Write a PNG: a few frames of one episode (I_marked, I_pure, depth map, marker motion), one "
                    "tile per episode (--gallery; a damaged episode is skipped and reported, and the command "
                    "then exits 1), or a demo press without any dataset.",
        epilog="examples:\n  univtac-data preview out/indenters --out sheet.png\n"
               "  univtac-data preview out/indenters --gallery --max-episodes 20 --out gallery.png\n"
               "  univtac-data preview --sensor gelsight_mini --demo sphere --out demo.png",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("path", nargs="?", help="dataset directory or fsspec URL (omit with --demo)")
    parser.add_argument("--out", help="PNG file to write (a contact sheet)")
    parser.add_argument("--video", metavar="OUT.mp4",
                        help="write the episode as an MP4: scene cameras, both pads' I_marked and depth maps, with "
                             "the primitive and normal forces as text (needs the [video] extra)")
    parser.add_argument("--rerun", metavar="FILE.rrd",
                        help="log the episode for the Rerun viewer: images, depth, markers as points, poses as "
                             "transforms (needs the [rerun] extra; open with `rerun FILE.rrd`)")
    parser.add_argument("--episode", help="episode id (default: the first)")
    parser.add_argument("--frames", type=positive_int, default=4,
                        help="frames shown, evenly spaced over those where the pad touches (default 4)")
    parser.add_argument("--pad", choices=("left", "right"), default="left", help="which pad (default left)")
    parser.add_argument("--gallery", action="store_true",
                        help="one tile per episode instead of one episode's frames: the pad at its deepest press, "
                             "or for a task episode at the expert's first correction in touch, beside the head "
                             "camera")
    parser.add_argument("--max-episodes", type=positive_int, default=42, metavar="N",
                        help="gallery: episodes shown, at least 1 (default 42)")
    parser.add_argument("--sensor", help=f"demo mode: sensor profile ({', '.join(SENSORS)})")
    parser.add_argument("--demo", help="demo mode: indenter (sphere, cylinder, punch, cross, two_spheres)")
    parser.add_argument("--method", choices=("geometric", "elastic"), default="elastic", help="demo contact model")
    parser.add_argument("--depth", type=float, help="demo press depth, mm (default: inside the safe range)")
    return parser


def _demo_frames(sensor: str, demo: str, method: str, depth: float | None, n: int) -> tuple[list[Any], str]:
    from univtac_data.generators.tactile import DEMO_INDENTERS, SheetFrame, demo_gap, simulate_frame

    if sensor not in SENSORS:
        raise DatasetError(f"--sensor {sensor}: unknown sensor; known sensors: {', '.join(SENSORS)}")
    if demo not in DEMO_INDENTERS:
        raise DatasetError(f"--demo {demo}: unknown demo indenter; known: {', '.join(DEMO_INDENTERS)}")
    profile = get_sensor(sensor)
    if depth is not None and not 0.0 < depth <= profile.gel_thickness_mm:  # NaN too
        raise DatasetError(f"--depth must be above 0 and at most the {profile.display_name}'s gel thickness, "
                           f"{profile.gel_thickness_mm:g} mm (got {depth})")
    final = depth if depth is not None else 0.5 * (profile.grasp_threshold_mm + profile.safe_indentation_mm)
    frames, state = [], None
    n = max(1, n)
    for k in range(n):
        d = final * (k + 1) / n
        shift = 0.1 * final * k  # a growing tangential drag so the markers show shear
        frame = simulate_frame(
            profile, demo_gap(profile, demo, d), method=method,  # type: ignore[arg-type]
            tangential_mm=(shift, 0.0), state=state, noise_seed=k,
        )
        state = frame.state
        frames.append(SheetFrame.from_frame(frame, f"d = {d:.2f} mm, dx = {shift:.2f} mm"))
    return frames, f"{profile.display_name}: {demo}, {method} contact"


def _dataset_frames(path: str, episode: str | None, n: int, pad: str) -> tuple[list[Any], str]:
    from univtac_data.generators.tactile import SheetFrame

    dataset = Dataset.open(path)
    ids = dataset.episode_ids
    if not ids:
        raise DatasetError(f"{path}: the dataset has no episodes")
    episode_id = episode if episode is not None else ids[0]
    if episode_id not in ids:
        raise DatasetError(f"{path}: no episode {episode_id!r} (episodes: {', '.join(ids[:5])}{'...' if len(ids) > 5 else ''})")
    with dataset.open_episode(episode_id) as handle:  # read only the frames shown
        meta = handle.meta
        if pad not in meta.pads:
            raise DatasetError(f"{path}: episode {episode_id!r} has no pad {pad!r} (pads: {', '.join(meta.pads)})")
        key = f"tactile/{pad}/"
        # a task episode's pad touches for part of it: spread the frames over that span, not over the approach
        touching = np.flatnonzero(_touches(handle, key))
        first, last = (int(touching[0]), int(touching[-1])) if touching.size else (0, meta.n_frames - 1)
        picks = np.unique(np.linspace(first, last, max(1, min(n, last - first + 1))).round().astype(int))
        ref = handle.read(key + "markers_ref_px")
        frames = [
            SheetFrame(handle.read(key + "marked_rgb", int(t)), handle.read(key + "pure_rgb", int(t)),
                       handle.read(key + "depth_um", int(t)).astype(np.float32) / 1000.0, ref,
                       handle.read(key + "markers_px", int(t)), f"frame {t}")
            for t in picks
        ]
    span = f"; shown: frames {first}-{last}, where the pad touches" if touching.size else ""
    return frames, f"{episode_id} ({meta.sensor}, pad {pad}, {meta.n_frames} frames{span})"


def _touches(handle: Any, key: str) -> np.ndarray:
    """(T,) bool: the frames in which the pad under ``key`` ("tactile/left/") touches, from its normal force
    (one number a frame, where the depth maps would be read whole)."""
    return handle.read(key + "normal_force_n") > 0.0


def recorded_corrections(meta: Any) -> list[tuple[int, str]]:
    """(frame, what) of each correction a task's expert recorded (``extra.task.memory.corrections``,
    spec/format.md: the frame its ``step`` count was taken at), in order; empty for an indenter episode, a
    task without corrections, or an ``extra`` that does not hold them (readers may ignore it, so a gallery
    never fails on it)."""
    try:
        return [(min(max(int(c["step"]), 0), meta.n_frames - 1), str(c["what"]))
                for c in meta.extra["task"]["memory"]["corrections"]]
    except (KeyError, TypeError, ValueError):
        return []


def _gallery_tile(handle: Any, pad: str) -> tuple[np.ndarray, str, bool]:
    """One episode's tile: I_marked of ``pad`` (the first pad if it has no such pad) at the first correction
    the task's expert made while that pad touched (a gallery is for looking at touch), else at the deepest
    press, with the first scene camera at that frame on its left when the episode has cameras. Returns (tile,
    caption, whether it shows a correction)."""
    from univtac_data.export.episode_video import resize_to_height

    meta = handle.meta
    key = f"tactile/{pad if pad in meta.pads else meta.pads[0]}/"
    touches = _touches(handle, key)
    touching = [(frame, what) for frame, what in recorded_corrections(meta) if touches[frame]]
    if touching:
        frame, what = touching[0]
        caption = f"{meta.name}, seed {meta.seed}: {what} (frame {frame})"
    else:
        frame = int(np.argmax(handle.read(key + "depth_um").reshape(meta.n_frames, -1).max(axis=1)))
        caption = f"{meta.name} ({meta.sensor})" if meta.kind != "task" else f"{meta.name}, seed {meta.seed}"
    marked = handle.read(key + "marked_rgb", frame)
    cameras = [resize_to_height(handle.read(f"scene/cameras/{meta.cameras[0].name}/rgb", frame), marked.shape[0])
               ] if meta.cameras else []
    return np.concatenate([*cameras, marked], axis=1), caption, bool(touching)


def _gallery_tiles(path: str, pad: str, limit: int) -> tuple[list[tuple[np.ndarray, str]], str, list[str]]:
    """One tile per episode (``_gallery_tile``). A damaged episode is skipped and reported (the third value:
    one line each)."""
    dataset = Dataset.open(path)
    if not dataset.episode_ids:
        raise DatasetError(f"{path}: the dataset has no episodes")
    tiles, failed, corrections = [], [], 0
    for episode_id in dataset.episode_ids[:limit]:
        where = dataset.loc.url_of(dataset.index[episode_id].path)
        try:
            with dataset.open_episode(episode_id) as handle:
                tile, caption, at_correction = _gallery_tile(handle, pad)
            tiles.append((tile, caption))
            corrections += at_correction
        except Exception as error:  # any reader error of a damaged file: skip the episode, report it
            text = str(error).splitlines()[0] if str(error) else type(error).__name__
            failed.append(text if text.startswith(where) else f"{where}: {type(error).__name__}: {text}")
    if not tiles:
        raise DatasetError(f"{path}: no episode could be read ({failed[0]})")
    shown = min(limit, len(dataset))
    moment = ("the expert's first correction in touch (else the deepest press)" if corrections
              else "each episode's deepest press")
    return tiles, f"{path}: {len(tiles)} of {len(dataset)} episodes, I_marked at {moment}", failed[: shown]


def _write_atomic(out: str, suffix: str, write: Any, make_folder: bool = False) -> Any:
    """Run ``write(tmp)`` into a temporary file beside ``out``, then rename it to ``out`` (no half file).
    ``make_folder``: make ``out``'s folder first if it does not exist."""
    target = os.path.abspath(out)
    folder = os.path.dirname(target)
    if make_folder:
        os.makedirs(folder, exist_ok=True)
    if not os.path.isdir(folder) or not os.access(folder, os.W_OK):
        raise DatasetError(f"{out}: cannot write there (no such folder, or not writable)")
    tmp = os.path.join(folder, f".tmp-{os.getpid()}-{os.path.basename(target)}")
    if not tmp.endswith(suffix):
        tmp += suffix
    try:
        result = write(tmp)
        os.replace(tmp, target)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
    return result


def _episode_views(args: argparse.Namespace) -> int:
    """``--video`` and ``--rerun``: one episode, whole."""
    from univtac_data.export.video import require_av

    if args.gallery or args.demo is not None or args.sensor is not None:
        raise DatasetError("--video and --rerun show one dataset episode; they do not combine with --gallery, "
                           "--sensor or --demo")
    if args.path is None:
        raise DatasetError("preview --video/--rerun: give a dataset PATH")
    if args.video:
        require_av()
    if args.rerun:
        from univtac_data.export.rerun_log import require_rerun

        require_rerun()
    dataset = Dataset.open(args.path)
    ids = dataset.episode_ids
    if not ids:
        raise DatasetError(f"{args.path}: the dataset has no episodes")
    episode_id = args.episode if args.episode is not None else ids[0]
    if episode_id not in ids:
        raise DatasetError(f"{args.path}: no episode {episode_id!r} (episodes: {', '.join(ids[:5])}"
                           f"{'...' if len(ids) > 5 else ''})")
    with dataset.open_episode(episode_id) as handle:
        if args.video:
            from univtac_data.export.episode_video import write_episode_video

            n, width, height = _write_atomic(args.video, ".mp4", lambda tmp: write_episode_video(handle, tmp))
            print(f"wrote {args.video} ({episode_id}: {n} frames, {width} x {height})")
        if args.rerun:
            from univtac_data.export.rerun_log import log_episode_rrd

            _write_atomic(args.rerun, ".rrd", lambda tmp: log_episode_rrd(handle, tmp))
            print(f"wrote {args.rerun} ({episode_id}; open it with: rerun {args.rerun})")
    return 0


def run(args: argparse.Namespace) -> int:
    from univtac_data.generators.tactile import contact_sheet, image_gallery

    if args.video or args.rerun:
        if args.out:
            raise DatasetError("preview: --out writes a contact sheet; give it in a separate run from "
                               "--video/--rerun")
        return _episode_views(args)
    if args.out is None:
        raise DatasetError("preview: give --out FILE.png, --video OUT.mp4 or --rerun FILE.rrd")

    check_output_file(args.out, "--out")
    if args.demo is not None or args.sensor is not None:
        if args.path is not None:
            raise DatasetError(f"{args.path}: give either a dataset PATH or --sensor/--demo, not both")
        frames, title = _demo_frames(args.sensor or "gelsight_mini", args.demo or "sphere", args.method, args.depth,
                                     args.frames)
    elif args.path is None:
        raise DatasetError("preview: give a dataset PATH, or --sensor NAME --demo INDENTER")
    elif args.gallery:
        tiles, title, failed = _gallery_tiles(args.path, args.pad, args.max_episodes)
        _write_atomic(args.out, ".png", lambda tmp: image_gallery(tiles, tmp, title=title), make_folder=True)
        print(f"wrote {args.out}")
        for line in failed:
            print(f"skipped: {line}", file=sys.stderr)
        return 1 if failed else 0
    else:
        frames, title = _dataset_frames(args.path, args.episode, args.frames, args.pad)
    _write_atomic(args.out, ".png", lambda tmp: contact_sheet(frames, tmp, title=title), make_folder=True)
    print(f"wrote {args.out}")
    return 0
