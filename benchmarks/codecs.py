"""Which lossless Blosc codec for the tactile RGB images: write and read cost against size, on generated frames.

    python benchmarks/codecs.py [--frames 20]    # GelSight Mini, all 14 indenters, both pads

One frame per chunk with Fletcher-32, as the format stores them; CPU time of one process. Writes
benchmarks/results/codecs.json. The spec's encoding choice (Zstandard level 1) quotes it.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import time

import h5py
import hdf5plugin
from common import RESULTS, machine

from univtac_data.generators.indenter_corpus import IndenterEpisodeSpec, run_indenter_episode
from univtac_data.generators.indenters import INDENTER_NAMES

CANDIDATES = [("zstd", 3), ("zstd", 1), ("lz4hc", 1), ("lz4", 1), ("lz4", 5), ("lz4", 9)]
FIELDS = ("tactile/left/marked_rgb", "tactile/left/pure_rgb", "tactile/right/marked_rgb", "tactile/right/pure_rgb")


def measure(images: list, cname: str, level: int) -> dict[str, float | str]:  # type: ignore[type-arg]
    """Write every image array (one frame per chunk) to an in-memory HDF5 file, read each frame back."""
    frames = sum(a.shape[0] for a in images) // len(FIELDS)
    sink = io.BytesIO()
    start = time.process_time()
    with h5py.File(sink, "w") as f:
        for k, array in enumerate(images):
            f.create_dataset(str(k), data=array, chunks=(1, *array.shape[1:]), fletcher32=True,
                             **hdf5plugin.Blosc(cname=cname, clevel=level, shuffle=hdf5plugin.Blosc.SHUFFLE))
    written = time.process_time()
    with h5py.File(sink, "r") as f:
        for k in range(len(images)):
            dataset = f[str(k)]
            for t in range(dataset.shape[0]):
                dataset[t]
    read = time.process_time()
    return {"codec": f"{cname}:{level}", "write_ms_per_frame": round((written - start) / frames * 1e3, 2),
            "read_ms_per_frame": round((read - written) / frames * 1e3, 2),
            "image_kib_per_frame": round(len(sink.getvalue()) / frames / 1024, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=20)
    args = parser.parse_args()
    episodes = [run_indenter_episode(IndenterEpisodeSpec("gelsight_mini", shape, 0, frames=args.frames))
                for shape in INDENTER_NAMES]
    images = [episode.arrays[path] for episode in episodes for path in FIELDS]
    rows = [measure(images, *c) for c in CANDIDATES]
    result = {"machine": machine(threads_used=1, packages=("numpy", "h5py", "hdf5plugin")),
              "episodes": f"gelsight_mini, the 14 indenters, {args.frames} frames each",
              "per_frame": "the four RGB images of a frame (I_marked and I_pure of both pads)", "rows": rows}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "codecs.json").write_text(json.dumps(result, indent=2) + "\n")
    json.dump(rows, sys.stdout, indent=1)


if __name__ == "__main__":
    main()
