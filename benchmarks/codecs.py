"""Which lossless Blosc codec for each per-pixel tactile field: write and read cost against size, on generated frames.

    python benchmarks/codecs.py [--frames 20]    # GelSight Mini, all 14 indenters, both pads, both contact models

Three field classes, each with its candidates: the RGB images (I_marked, I_pure), the depth in micrometres
(uint16) and the contact mask (uint8 0/1). One frame per chunk with Fletcher-32, as the format stores them;
CPU time of one process; per frame = both pads. Writes benchmarks/results/codecs.json. The spec's encoding
table (spec/format.md, section 9, and univtac_data/storage/encoding.py) quotes it.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import time

import h5py
import hdf5plugin
import numpy as np
from common import RESULTS, machine

from univtac_data.generators.indenter_corpus import IndenterEpisodeSpec, run_indenter_episode
from univtac_data.generators.indenters import INDENTER_NAMES

SHUFFLE = {"byte": hdf5plugin.Blosc.SHUFFLE, "bit": hdf5plugin.Blosc.BITSHUFFLE}
FIELD_CLASSES = {  # class -> (array names under tactile/<pad>/, candidates (cname, level, shuffle))
    "image": (("marked_rgb", "pure_rgb"),
              [("zstd", 3, "byte"), ("zstd", 1, "byte"), ("lz4hc", 1, "byte"), ("lz4", 1, "byte"), ("lz4", 9, "byte")]),
    "depth": (("depth_um",),
              [("zstd", 1, "bit"), ("zstd", 1, "byte"), ("lz4", 1, "byte"), ("lz4", 1, "bit"), ("blosclz", 1, "byte")]),
    "mask": (("contact_mask",),
             [("zstd", 1, "byte"), ("lz4", 1, "byte"), ("blosclz", 1, "byte")]),
}


def measure(arrays: list[np.ndarray], frames: int, cname: str, level: int, shuffle: str) -> dict[str, float | str]:
    """Write every array (one frame per chunk) to an in-memory HDF5 file, read each frame back."""
    sink = io.BytesIO()
    start = time.process_time()
    with h5py.File(sink, "w") as f:
        for k, array in enumerate(arrays):
            f.create_dataset(str(k), data=array, chunks=(1, *array.shape[1:]), fletcher32=True,
                             **hdf5plugin.Blosc(cname=cname, clevel=level, shuffle=SHUFFLE[shuffle]))
    written = time.process_time()
    with h5py.File(sink, "r") as f:
        for k in range(len(arrays)):
            dataset = f[str(k)]
            for t in range(dataset.shape[0]):
                dataset[t]
    read = time.process_time()
    return {"codec": f"{cname}:{level}:{shuffle}", "write_ms_per_frame": round((written - start) / frames * 1e3, 3),
            "read_ms_per_frame": round((read - written) / frames * 1e3, 3),
            "kib_per_frame": round(len(sink.getvalue()) / frames / 1024, 2)}


def stored(array: np.ndarray) -> np.ndarray:
    """The array as the format stores it (bool masks as uint8 0/1)."""
    return array.astype(np.uint8) if array.dtype == bool else array


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=20)
    args = parser.parse_args()
    rows = []
    for contact in ("geometric", "elastic"):
        episodes = [run_indenter_episode(IndenterEpisodeSpec("gelsight_mini", shape, 0, frames=args.frames,
                                                             contact_method=contact)) for shape in INDENTER_NAMES]
        frames = sum(episode.meta.n_frames for episode in episodes)
        for field_class, (names, candidates) in FIELD_CLASSES.items():
            arrays = [stored(episode.arrays[f"tactile/{pad}/{name}"])
                      for episode in episodes for pad in ("left", "right") for name in names]
            for candidate in candidates:
                row = {"contact": contact, "field": field_class, **measure(arrays, frames, *candidate)}
                rows.append(row)
                print(json.dumps(row), file=sys.stderr)
    result = {"machine": machine(threads_used=1, packages=("numpy", "h5py", "hdf5plugin")),
              "episodes": f"gelsight_mini, the 14 indenters, {args.frames} frames each, geometric and elastic",
              "per_frame": {name: f"both pads' {', '.join(names)}" for name, (names, _) in FIELD_CLASSES.items()},
              "rows": rows}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "codecs.json").write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
