"""How to store each per-pixel tactile field: write and read cost against size, on generated frames.

    python benchmarks/codecs.py [--frames 20] [--sensors gelsight_mini,gf225]

For each sensor (native resolution), all 14 indenters, both pads and both contact models, three field
classes with their candidates:

* images (I_marked and I_pure together): stored as they are (format 1.0) or as residuals (format 2.0:
  I_marked - I_pure, I_pure - pure_ref_rgb, modulo 256), with Blosc's automatic block size, 512 KiB blocks
  (the format's choice) or 128 KiB blocks (its earlier one), Zstandard at levels 1 and 3, LZ4;
* depth in micrometres (uint16): byte- or bit-shuffle, block size, Zstandard or LZ4;
* the contact mask (uint8 0/1).

Chunks are one frame each with Fletcher-32, written by the package's own chunk writer into an in-memory HDF5
file and read back frame by frame through h5py (a residual read adds its base back, as the reader does).
CPU time of one process; per frame = both pads. Writes benchmarks/results/codecs.json and
docs/figures/codecs.png (bytes against write time, per field class); the spec's encoding section
(spec/format.md, section 9) and univtac_data/storage/encoding.py quote it. ``--chart-only`` redraws the
figure from the JSON.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import time
from dataclasses import dataclass

import h5py
import hdf5plugin
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import FIGURES, RESULTS, machine  # noqa: E402

from univtac_data.generators.indenters.corpus import IndenterEpisodeSpec, run_indenter_episode
from univtac_data.generators.indenters.shapes import INDENTER_NAMES
from univtac_data.storage.encoding import FRAME_BLOCK_BYTES, EncodedArray, Encoding
from univtac_data.storage.hdf5_store import write_frame_chunks

PADS = ("left", "right")


@dataclass(frozen=True)
class Candidate:
    cname: str
    level: int
    shuffle: str  # "byte" or "bit"
    blocksize: int  # bytes, 0: Blosc chooses
    residual: bool = False  # images only: the 2.0 residual coding

    @property
    def name(self) -> str:
        block = f"{self.blocksize // 1024}k" if self.blocksize else "auto"
        return f"{'residual' if self.residual else 'plain'} {self.cname}:{self.level}:{self.shuffle} blocks {block}"


EARLIER_BLOCK_BYTES = 1 << 17  # the block size one-frame chunks had before 512 KiB (128 KiB)
CANDIDATES = {
    "image": [Candidate("zstd", 1, "byte", 0), Candidate("zstd", 1, "byte", FRAME_BLOCK_BYTES),
              Candidate("zstd", 1, "byte", 0, True), Candidate("zstd", 1, "byte", FRAME_BLOCK_BYTES, True),
              Candidate("zstd", 3, "byte", FRAME_BLOCK_BYTES, True), Candidate("lz4", 1, "byte", FRAME_BLOCK_BYTES, True),
              Candidate("zstd", 1, "byte", EARLIER_BLOCK_BYTES, True)],
    "depth": [Candidate("zstd", 1, "byte", 0), Candidate("zstd", 1, "byte", FRAME_BLOCK_BYTES),
              Candidate("zstd", 1, "bit", FRAME_BLOCK_BYTES), Candidate("lz4", 1, "byte", FRAME_BLOCK_BYTES),
              Candidate("zstd", 1, "byte", EARLIER_BLOCK_BYTES)],
    "mask": [Candidate("zstd", 1, "byte", 0), Candidate("zstd", 1, "byte", FRAME_BLOCK_BYTES),
             Candidate("lz4", 1, "byte", FRAME_BLOCK_BYTES), Candidate("zstd", 1, "byte", EARLIER_BLOCK_BYTES)],
}
FORMAT_CHOICE = {"image": CANDIDATES["image"][3], "depth": CANDIDATES["depth"][1], "mask": CANDIDATES["mask"][1]}


def _items(episode, field_class: str, candidate: Candidate) -> list[EncodedArray]:
    """The arrays of one field class of an episode, as the writer would hand them to the chunk writer."""
    out = []
    for pad in PADS:
        get = lambda key: episode.arrays[f"tactile/{pad}/{key}"]  # noqa: E731
        if field_class == "image":
            pairs = [("marked_rgb", get("marked_rgb"), get("pure_rgb")), ("pure_rgb", get("pure_rgb"), get("pure_ref_rgb"))]
        else:
            data = get("depth_um" if field_class == "depth" else "contact_mask").astype(
                np.uint16 if field_class == "depth" else np.uint8)
            pairs = [(field_class, data, None)]
        for key, data, base in pairs:
            encoding = Encoding((1, *data.shape[1:]), None, candidate.cname, candidate.level, candidate.shuffle,  # type: ignore[arg-type]
                                str(data.dtype), candidate.blocksize, True)
            residual = candidate.residual and base is not None
            out.append(EncodedArray(f"{pad}/{key}", data, encoding, "base" if residual else None,
                                    base if residual else None))
    return out


def measure(episodes: list, field_class: str, candidate: Candidate) -> dict[str, float | str]:
    """Write every array to an in-memory HDF5 file with the package's chunk writer; read each frame back."""
    frames = sum(episode.meta.n_frames for episode in episodes)
    per_episode = [_items(episode, field_class, candidate) for episode in episodes]
    sink = io.BytesIO()
    start = time.process_time()
    with h5py.File(sink, "w") as f:
        for k, items in enumerate(per_episode):
            for item in items:
                dataset = f.create_dataset(f"{k}/{item.path}", shape=item.data.shape, dtype=item.data.dtype,
                                           chunks=item.encoding.chunks, fletcher32=True,
                                           **hdf5plugin.Blosc(cname=candidate.cname, clevel=candidate.level))
                write_frame_chunks(dataset, item)
    written = time.process_time()
    with h5py.File(sink, "r") as f:
        for k, items in enumerate(per_episode):
            for item in items:
                dataset = f[f"{k}/{item.path}"]
                for t in range(dataset.shape[0]):
                    frame = dataset[t]
                    if item.base is not None:  # the reader adds the base back (itself decoded for I_marked)
                        np.add(frame, item.base[t] if item.base.ndim == item.data.ndim else item.base, out=frame)
    read = time.process_time()
    return {"codec": candidate.name, "format_choice": candidate == FORMAT_CHOICE[field_class],
            "write_ms_per_frame": round((written - start) / frames * 1e3, 3),
            "read_ms_per_frame": round((read - written) / frames * 1e3, 3),
            "kib_per_frame": round(len(sink.getvalue()) / frames / 1024, 2)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--sensors", default="gelsight_mini,gf225")
    parser.add_argument("--chart-only", action="store_true", help="redraw the figure from the results JSON")
    args = parser.parse_args()
    if args.chart_only:
        chart(json.loads((RESULTS / "codecs.json").read_text()), FIGURES / "codecs.png")
        return
    rows = []
    for sensor in args.sensors.split(","):
        for contact in ("geometric", "elastic"):
            episodes = [run_indenter_episode(IndenterEpisodeSpec(sensor, shape, 0, frames=args.frames,
                                                                 contact_method=contact)) for shape in INDENTER_NAMES]
            for field_class, candidates in CANDIDATES.items():
                for candidate in candidates:
                    row = {"sensor": sensor, "contact": contact, "field": field_class,
                           **measure(episodes, field_class, candidate)}
                    rows.append(row)
                    print(json.dumps(row), file=sys.stderr)
    result = {"machine": machine(threads_used=1, packages=("numpy", "h5py", "hdf5plugin", "numcodecs")),
              "episodes": f"{args.sensors}, the 14 indenters, {args.frames} frames each, geometric and elastic",
              "per_frame": {"image": "both pads' marked_rgb and pure_rgb", "depth": "both pads' depth_um",
                            "mask": "both pads' contact_mask"},
              "rows": rows}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "codecs.json").write_text(json.dumps(result, indent=2) + "\n")
    chart(result, FIGURES / "codecs.png")


def chart(result: dict, path: object) -> None:  # type: ignore[type-arg]
    """One panel per sensor and contact model: KiB a frame against write ms a frame, a marker per candidate
    (colour: field class), the format's choices ringed."""
    panels = sorted({(r["sensor"], r["contact"]) for r in result["rows"]})
    colours = {"image": "tab:blue", "depth": "tab:orange", "mask": "tab:green"}
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 4.2), squeeze=False)
    for ax, (sensor, contact) in zip(axes[0], panels):
        for r in result["rows"]:
            if (r["sensor"], r["contact"]) != (sensor, contact):
                continue
            ax.scatter(r["write_ms_per_frame"], r["kib_per_frame"], color=colours[r["field"]], s=18)
            if r["format_choice"]:
                ax.scatter(r["write_ms_per_frame"], r["kib_per_frame"], facecolors="none", edgecolors="k", s=90)
            ax.annotate(r["codec"].replace(" blocks ", " "), (r["write_ms_per_frame"], r["kib_per_frame"]),
                        fontsize=5, xytext=(3, 2), textcoords="offset points")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{sensor}, {contact}", fontsize=9)
        ax.set_xlabel("write, ms a frame (both pads)")
    axes[0][0].set_ylabel("KiB a frame on disk")
    for field_class, colour in colours.items():
        axes[0][0].scatter([], [], color=colour, label=field_class)
    axes[0][0].scatter([], [], facecolors="none", edgecolors="k", label="the format's choice")
    axes[0][0].legend(fontsize=7)
    fig.suptitle(f"Tactile field codecs, one core ({result['machine']['cpu']})", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
