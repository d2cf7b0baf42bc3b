"""The sampler layer: index tables computed once, before any array is read (no torch, no I/O).

``FrameTable`` lists one row per (episode, frame, pad) for the encoder loader; ``WindowTable`` one row per
(episode, step) for the policy loader, with the padding each window needs at the episode's edges. The
torch datasets only look rows up, so the tables can be tested (and reused by other frameworks) alone.

Window edges, with an episode of T = 5 frames (s_0 .. s_4, actions a_0 .. a_4), ``history = 3`` and
``chunk = 4`` (robomimic's frame stacking, ACT's action chunks)::

    step 0: observations (s_0, s_0, s_0)   obs_is_pad    (T, T, F)
            actions      (a_0, a_1, a_2, a_3)  action_is_pad (F, F, F, F)
    step 1: observations (s_0, s_0, s_1)   obs_is_pad    (T, F, F)
    step 3: observations (s_1, s_2, s_3)   obs_is_pad    (F, F, F)
            actions      (a_3, a_4, a_4, a_4)  action_is_pad (F, F, T, T)
    step 4: actions      (a_4, a_4, a_4, a_4)  action_is_pad (F, T, T, T)

The history is padded by repeating the first frame, the chunk by repeating the last action (or zeros,
see ``PolicyChunkConfig.action_pad``); padded entries are flagged so a loss can mask them. ``a_t`` is the
command sent at frame t and held until t + 1, so the chunk for step t starts with ``a_t``: the first
thing to do after seeing ``s_t``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Window:
    """Frame indices of one training window, all within [0, T - 1]."""

    obs_frames: np.ndarray      # (history,) int64, oldest first, the last is the step itself
    obs_is_pad: np.ndarray      # (history,) bool, True where the first frame was repeated
    action_frames: np.ndarray   # (chunk,) int64, starting at the step
    action_is_pad: np.ndarray   # (chunk,) bool, True past the episode's last frame


def window(step: int, n_frames: int, history: int, chunk: int) -> Window:
    """The window at ``step`` of an episode of ``n_frames`` frames (see the module docstring)."""
    if not 0 <= step < n_frames:
        raise IndexError(f"step must be in [0, {n_frames - 1}] (got {step})")
    obs = np.arange(step - history + 1, step + 1, dtype=np.int64)
    act = np.arange(step, step + chunk, dtype=np.int64)
    return Window(obs_frames=np.maximum(obs, 0), obs_is_pad=obs < 0,
                  action_frames=np.minimum(act, n_frames - 1), action_is_pad=act >= n_frames)


class FrameTable:
    """One row per (episode, frame, pad), episode-major, then frame, then pad.

    Columns (equal length R): ``episode`` int32 index into the loader's episode list, ``frame`` int32,
    ``pad`` int16 index into ``pad_names``.
    """

    def __init__(self, n_frames: Sequence[int], pads: Sequence[Sequence[str]]) -> None:
        if len(n_frames) != len(pads):
            raise ValueError(f"need one pad list per episode (got {len(n_frames)} episodes, {len(pads)} lists)")
        self.pad_names: list[str] = sorted({p for ep_pads in pads for p in ep_pads})
        code = {name: k for k, name in enumerate(self.pad_names)}
        episode, frame, pad = [], [], []
        for k, (count, ep_pads) in enumerate(zip(n_frames, pads)):
            codes = np.array([code[p] for p in ep_pads], np.int16)
            episode.append(np.full(count * len(codes), k, np.int32))
            frame.append(np.repeat(np.arange(count, dtype=np.int32), len(codes)))
            pad.append(np.tile(codes, count))
        self.episode = np.concatenate(episode) if episode else np.zeros(0, np.int32)
        self.frame = np.concatenate(frame) if frame else np.zeros(0, np.int32)
        self.pad = np.concatenate(pad) if pad else np.zeros(0, np.int16)

    def __len__(self) -> int:
        return len(self.episode)

    def row(self, index: int) -> tuple[int, int, str]:
        """``(episode, frame, pad name)`` of row ``index``."""
        return int(self.episode[index]), int(self.frame[index]), self.pad_names[int(self.pad[index])]


class WindowTable:
    """One row per (episode, step), every step of every episode, with the window's edge padding.

    Columns (equal length R): ``episode`` int32, ``step`` int32, ``pad_before`` int32 (repeated first
    frames in the history), ``pad_after`` int32 (padded actions at the chunk's end).
    """

    def __init__(self, n_frames: Sequence[int], history: int, chunk: int) -> None:
        if history < 1 or chunk < 1:
            raise ValueError(f"history and chunk must be >= 1 (got history={history}, chunk={chunk})")
        self.history, self.chunk = history, chunk
        self.n_frames = np.asarray(n_frames, np.int64)
        self.episode = np.repeat(np.arange(len(n_frames), dtype=np.int32), self.n_frames)
        starts = np.concatenate([[0], np.cumsum(self.n_frames)[:-1]]) if len(n_frames) else np.zeros(0, np.int64)
        self.step = (np.arange(len(self.episode)) - np.repeat(starts, self.n_frames)).astype(np.int32)
        self.pad_before = np.maximum(history - 1 - self.step, 0).astype(np.int32)
        self.pad_after = np.maximum(self.step + chunk - self.n_frames[self.episode], 0).astype(np.int32)

    def __len__(self) -> int:
        return len(self.episode)

    def window(self, index: int) -> tuple[int, Window]:
        """``(episode, window)`` of row ``index``."""
        episode = int(self.episode[index])
        return episode, window(int(self.step[index]), int(self.n_frames[episode]), self.history, self.chunk)
