"""``PolicyChunkDataset``: per step, an observation history and the next ``chunk`` actions (ACT-style).

A sample for step t of an episode (shapes with ``Hh = history``, ``C = chunk``)::

    obs/<key>       (Hh, ...)  the key's frames t - Hh + 1 .. t, oldest first (see conversions below)
    obs_is_pad      (Hh,) bool   True where frame 0 was repeated because t - k < 0
    action          (C, 8) float32  robot/action at t .. t + C - 1 (ee x, y, z m; quaternion w, x, y, z;
                                    gripper width m), normalised if ``normalize`` says so
    action_is_pad   (C,) bool    True past the episode's last frame (mask these in the loss)
    episode_id (str), step (int), dataset (int)

With T = 5, history 3, chunk 4: step 0 gives observations (s_0, s_0, s_0) with obs_is_pad (T, T, F) and
actions (a_0, a_1, a_2, a_3); step 3 gives (s_1, s_2, s_3) and (a_3, a_4, a_4, a_4) with action_is_pad
(F, F, T, T). ``sampler.py`` has the full table.

Observation conversions, by the stored field: uint8 images (tactile ``marked_rgb``/``pure_rgb``, camera
``rgb``) -> (Hh, 3, h, w) float32 in [0, 1]; ``tactile/{pad}/depth_um`` -> key ``tactile/{pad}/depth_mm``,
(Hh, 1, H, W) float32 mm; ``contact_mask`` -> (Hh, 1, H, W) bool; camera ``depth_m`` -> (Hh, 1, h, w)
float32 m; ``markers_px`` -> (Hh, N, 2) float32 px; low-dimensional arrays (``robot/ee_pose`` ...) ->
(Hh, D) float32 (scalars get D = 1), normalised like the actions; ``scene/primitive`` and
``timestamps_ns`` -> (Hh,) int64.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import torch

from univtac_data.schema.fields import field_for_path

from univtac_data.loaders.episodes import EpisodeReader, EpisodeRef, PathLike, as_path_list, open_selected, require_paths
from univtac_data.loaders.frames import image_chw
from univtac_data.loaders.normalize import NORMALIZE_MODES, NormalizeMode, Normalizer
from univtac_data.loaders.sampler import Window, WindowTable
from univtac_data.loaders.split import Split
from univtac_data.loaders.stats import FieldStats, is_lowdim, load_or_compute_stats, merge_all

Sample = dict[str, Any]

DEFAULT_OBS_KEYS: tuple[str, ...] = ("robot/ee_pose", "robot/gripper_width_m", "tactile/left/marked_rgb",
                                     "tactile/right/marked_rgb")
#: ``agent_pos``: not a stored field but the task environments' observation of the same name, (Hh, 8)
#: float32: ``robot/ee_pose`` (x, y, z m; w, x, y, z) then ``robot/gripper_width_m`` (m), each part
#: normalised by its own field's statistics. A policy trained on it sees what ``univtac-data evaluate`` feeds it.
AGENT_POS = "agent_pos"
AGENT_POS_PARTS: tuple[str, ...] = ("robot/ee_pose", "robot/gripper_width_m")
#: What a visuo-tactile policy on task episodes observes, as the environments name it.
TASK_OBS_KEYS: tuple[str, ...] = ("scene/cameras/head/rgb", "scene/cameras/wrist/rgb", "tactile/left/marked_rgb",
                                  "tactile/right/marked_rgb", AGENT_POS)


@dataclass(frozen=True)
class PolicyChunkConfig:
    """What a ``PolicyChunkDataset`` serves."""

    obs_keys: tuple[str, ...] = DEFAULT_OBS_KEYS  # stored per-frame paths to observe
    history: int = 1                     # observed frames per step, the step's own frame last
    chunk: int = 50                      # actions per step (ACT's default chunk)
    action_key: str = "robot/action"     # what to predict
    action_pad: Literal["repeat", "zero"] = "repeat"  # padded actions: the last action again, or 0 after
    #                                                   normalisation (ACT); either way flagged in action_is_pad
    normalize: NormalizeMode = "none"    # actions and low-dim observations; see normalize.py
    normalize_eps: float = 1e-4          # spread below which a component is only centred
    sensors: tuple[str, ...] | None = None   # keep only these sensor profiles; None: all
    names: tuple[str, ...] | None = None     # keep only these task names; None: all
    episodes: tuple[str, ...] | None = None  # explicit episode ids; None: all
    split: Split = "all"                 # "train" / "val" by hash of the episode id, or "all"
    val_fraction: float = 0.1
    split_seed: int = 0
    max_open_episodes: int = 16          # open handles kept per process (LRU)

    def __post_init__(self) -> None:
        if self.history < 1 or self.chunk < 1:
            raise ValueError(f"history and chunk must be >= 1 (got history={self.history}, chunk={self.chunk})")
        if self.action_pad not in ("repeat", "zero"):
            raise ValueError(f"action_pad must be 'repeat' or 'zero' (got {self.action_pad!r})")
        if self.normalize not in NORMALIZE_MODES:
            raise ValueError(f"normalize must be one of {', '.join(NORMALIZE_MODES)} (got {self.normalize!r})")
        for key in (*self.obs_keys, self.action_key):
            if key == AGENT_POS and key != self.action_key:
                continue
            spec = field_for_path(key)
            if spec is None or spec.sampling != "per_frame":
                raise ValueError(f"observation and action keys must be per-frame array paths such as "
                                 f"'robot/ee_pose' or 'tactile/left/marked_rgb' (got {key!r})")
        if not is_lowdim(self.action_key):
            raise ValueError(f"action_key must be a low-dimensional float array (got {self.action_key!r})")


def _tuple(value: Sequence[str] | str | None) -> tuple[str, ...] | None:
    if value is None:
        return None
    return (value,) if isinstance(value, str) else tuple(value)


def obs_name(key: str) -> str:
    """The sample key of stored path ``key`` (depth is served in mm, so its name says mm)."""
    return key[: -len("depth_um")] + "depth_mm" if key.endswith("/depth_um") else key


class PolicyChunkDataset(torch.utils.data.Dataset[Sample]):
    """Map-style dataset over every step of every selected episode (see the module docstring).

    Owns the episode list (``episodes``), the window table (``table``, a ``WindowTable``), an
    ``EpisodeReader`` (lazy, per process), the statistics (``stats``: stored path -> ``FieldStats``,
    merged over the datasets; each dataset's own in ``dataset_stats``, saved in its ``meta/stats.json``)
    and the ``normalizer`` built from them (use ``normalizer.inverse(action_key, ...)`` on predictions).
    """

    def __init__(self, path_or_paths: PathLike | Sequence[PathLike], *,
                 obs_keys: Sequence[str] = DEFAULT_OBS_KEYS, history: int = 1, chunk: int = 50,
                 action_key: str = "robot/action", action_pad: Literal["repeat", "zero"] = "repeat",
                 normalize: NormalizeMode = "none", normalize_eps: float = 1e-4,
                 sensors: Sequence[str] | str | None = None, names: Sequence[str] | str | None = None,
                 episodes: Sequence[str] | None = None, split: Split = "all", val_fraction: float = 0.1,
                 split_seed: int = 0, max_open_episodes: int = 16,
                 transform: Callable[[Sample], Sample] | None = None) -> None:
        config = PolicyChunkConfig(obs_keys=tuple(obs_keys), history=history, chunk=chunk, action_key=action_key,
                                   action_pad=action_pad, normalize=normalize, normalize_eps=normalize_eps,
                                   sensors=_tuple(sensors), names=_tuple(names), episodes=_tuple(episodes),
                                   split=split, val_fraction=val_fraction, split_seed=split_seed,
                                   max_open_episodes=max_open_episodes)
        self._setup(as_path_list(path_or_paths), config, transform)

    @classmethod
    def from_config(cls, path_or_paths: PathLike | Sequence[PathLike], config: PolicyChunkConfig,
                    transform: Callable[[Sample], Sample] | None = None) -> PolicyChunkDataset:
        self = cls.__new__(cls)
        self._setup(as_path_list(path_or_paths), config, transform)
        return self

    def _setup(self, paths: list[str], config: PolicyChunkConfig, transform: Callable[[Sample], Sample] | None) \
            -> None:
        self.config = config
        self.transform = transform
        self.datasets, self.episodes = open_selected(paths, config)
        stored = [part for key in config.obs_keys for part in (AGENT_POS_PARTS if key == AGENT_POS else (key,))]
        require_paths(self.episodes, [*stored, config.action_key], self.datasets)
        self.table = WindowTable([ref.n_frames for ref in self.episodes], config.history, config.chunk)
        self.reader = EpisodeReader(self.datasets, max_open=config.max_open_episodes)
        self.dataset_stats: list[dict[str, FieldStats]] = []
        self.stats_computed: list[bool] = []  # per dataset: computed now (True) or read from meta/stats.json
        for ds in self.datasets:
            stats, computed = load_or_compute_stats(ds)
            self.dataset_stats.append(stats)
            self.stats_computed.append(computed)
        self.stats = merge_all(self.dataset_stats)
        self.normalizer = Normalizer(self.stats, config.normalize, config.normalize_eps)

    def __len__(self) -> int:
        return len(self.table)

    def __getitem__(self, index: int) -> Sample:
        if not -len(self) <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} steps")
        episode, win = self.table.window(index % len(self))
        ref = self.episodes[episode]
        sample: Sample = {
            "obs": {obs_name(key): self._observe(ref, key, win) for key in self.config.obs_keys},
            "obs_is_pad": torch.from_numpy(win.obs_is_pad),
            "action": self._actions(ref, win),
            "action_is_pad": torch.from_numpy(win.action_is_pad),
            "episode_id": ref.episode_id, "step": int(win.obs_frames[-1]), "dataset": ref.dataset,
        }
        return self.transform(sample) if self.transform is not None else sample

    def _actions(self, ref: EpisodeRef, win: Window) -> torch.Tensor:
        key = self.config.action_key
        actions = torch.from_numpy(self.reader.read(ref, key)[win.action_frames].astype(np.float32))
        if self.config.normalize != "none":
            actions = self.normalizer.forward(key, actions)
        if self.config.action_pad == "zero":
            actions[torch.from_numpy(win.action_is_pad)] = 0.0
        return actions

    def _observe(self, ref: EpisodeRef, key: str, win: Window) -> torch.Tensor:
        if key == AGENT_POS:
            parts = [self._observe(ref, part, win) for part in AGENT_POS_PARTS]
            return torch.cat(parts, dim=1)
        frames = win.obs_frames
        lo, hi = int(frames.min()), int(frames.max())
        # Read the covered range once (one call, consecutive chunks) and repeat padded frames in memory.
        values = self.reader.read(ref, key, slice(lo, hi + 1))[frames - lo]
        spec = field_for_path(key)
        assert spec is not None  # checked by PolicyChunkConfig
        if spec.dtype == "uint8" and values.ndim == 4:
            return torch.stack([image_chw(v) for v in values])
        if key.endswith("/depth_um"):
            return torch.from_numpy(values.astype(np.float32) * np.float32(1e-3))[:, None]
        if values.ndim == 3 and spec.codec in ("image", "depth"):
            return torch.from_numpy(np.ascontiguousarray(values))[:, None]
        if is_lowdim(key):
            out = torch.from_numpy(values.astype(np.float32))
            if self.config.normalize != "none":
                out = self.normalizer.forward(key, out)
            return out[:, None] if out.ndim == 1 else out
        if np.issubdtype(values.dtype, np.integer):
            return torch.from_numpy(values.astype(np.int64))
        return torch.from_numpy(np.ascontiguousarray(values))
