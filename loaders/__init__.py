"""PyTorch loaders for univtac-data datasets, in three layers (as diffusion_policy's):

* episode store (``episodes.py``): which episodes, and a per-process LRU of open handles, with the layouts
  of HDF5 episodes kept after closing them (``layouts.py``, ``files.py``);
* sampler (``sampler.py``): index tables of frames and windows, computed once, no I/O;
* torch datasets (``frames.py``, ``policy.py``): look a row up, read, convert to tensors.

``TactileFrameDataset`` serves encoder-pretraining samples (one per frame and pad); ``PolicyChunkDataset``
serves policy-learning windows (observation history, action chunk, padding masks) with normalisation
statistics saved in each dataset's ``meta/stats.json``. Both work with ``DataLoader(num_workers > 0)``,
both storage backends and several datasets at once. See ``docs/loaders.md``.

PyTorch is an optional extra: the rest of univtac-data (generate, validate, convert, ...) runs without it.
"""

try:
    import torch  # noqa: F401
except ModuleNotFoundError as _error:
    if _error.name != "torch":
        raise
    raise ModuleNotFoundError("univtac_data.loaders needs PyTorch, which is not installed: "
                              "pip install 'univtac-data[torch]' (or [train])", name="torch") from None

from univtac_data.loaders.batching import SensorBatchSampler
from univtac_data.loaders.episodes import EpisodeReader, EpisodeRef, select_episodes
from univtac_data.loaders.frame_batches import FrameBatchLoader
from univtac_data.loaders.frames import ENCODER_TARGETS, FRAME_FIELDS, TactileFrameConfig, TactileFrameDataset, \
    to_float
from univtac_data.loaders.normalize import Normalizer
from univtac_data.loaders.policy import AGENT_POS, TASK_OBS_KEYS, PolicyChunkConfig, PolicyChunkDataset
from univtac_data.loaders.sampler import FrameTable, Window, WindowTable, window
from univtac_data.loaders.split import split_episode_ids, split_of
from univtac_data.loaders.stats import STATS_PATH, FieldStats, compute_stats, load_or_compute_stats
from univtac_data.loaders.transforms import Resize

__all__ = [
    "AGENT_POS", "TASK_OBS_KEYS", "ENCODER_TARGETS", "FRAME_FIELDS", "STATS_PATH", "EpisodeReader", "EpisodeRef", "FieldStats", "FrameBatchLoader",
    "FrameTable", "Normalizer", "PolicyChunkConfig", "PolicyChunkDataset", "Resize", "SensorBatchSampler",
    "TactileFrameConfig", "TactileFrameDataset", "Window", "WindowTable", "compute_stats", "load_or_compute_stats",
    "select_episodes", "split_episode_ids", "split_of", "to_float", "window",
]
