"""Which lossless codec for tactile arrays: write and read cost against size, on a generated episode.

    python benchmarks/codecs.py [DATASET]    # default: a fresh 40-frame GelSight Mini cross episode

Writes benchmarks/results/codecs.json. The spec's encoding choice (Blosc Zstandard level 1) quotes it.
"""

from __future__ import annotations

import io
import json
import sys
import time

import h5py
import hdf5plugin
from common import RESULTS, machine

from univtac_data.generators.indenter_corpus import IndenterEpisodeSpec, run_indenter_episode

CANDIDATES = [("zstd", 3, "byte"), ("zstd", 1, "byte"), ("zstd", 1, "bit"), ("lz4", 5, "byte"), ("lz4hc", 1, "byte")]
FIELDS = ("tactile/left/marked_rgb", "tactile/left/pure_rgb", "tactile/left/depth_um", "tactile/left/contact_mask")


def measure(arrays: dict, cname: str, level: int, shuffle: str) -> dict[str, float]:  # type: ignore[type-arg]
    frames = next(iter(arrays.values())).shape[0]
    sink = io.BytesIO()
    start = time.process_time()
    with h5py.File(sink, "w") as f:
        for path, array in arrays.items():
            bit = shuffle == "bit" or not path.endswith("_rgb")  # depth and masks are always bit-shuffled
            mode = hdf5plugin.Blosc.BITSHUFFLE if bit else hdf5plugin.Blosc.SHUFFLE
            f.create_dataset(path, data=array.astype("uint8") if array.dtype == bool else array,
                             chunks=(1, *array.shape[1:]), **hdf5plugin.Blosc(cname=cname, clevel=level, shuffle=mode))
    written = time.process_time()
    with h5py.File(sink, "r") as f:
        for t in range(frames):
            for path in arrays:
                f[path][t]
    read = time.process_time()
    return {"codec": f"{cname}:{level} {shuffle}-shuffle", "write_ms_per_pad_frame": round((written - start) / frames * 1e3, 2),
            "read_ms_per_pad_frame": round((read - written) / frames * 1e3, 2),
            "kib_per_pad_frame": round(len(sink.getvalue()) / frames / 1024, 1)}


def main() -> None:
    episode = run_indenter_episode(IndenterEpisodeSpec("gelsight_mini", "cross", 0, frames=40))
    arrays = {path: episode.arrays[path] for path in FIELDS}
    rows = [measure(arrays, *c) for c in CANDIDATES]
    result = {"machine": machine(threads_used=1, packages=("numpy", "h5py", "hdf5plugin")),
              "episode": "gelsight_mini cross, 40 frames, one pad", "fields": FIELDS, "rows": rows}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "codecs.json").write_text(json.dumps(result, indent=2) + "\n")
    json.dump(rows, sys.stdout, indent=1)


if __name__ == "__main__":
    main()
