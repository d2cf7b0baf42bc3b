"""Episode-level train/validation split: deterministic, by episode id, stable as a dataset grows.

An episode's part depends only on its id and the seed: ``u = sha256(f"{seed}:{episode_id}")`` read as a
number in [0, 1); the episode is in ``val`` when ``u < val_fraction``. Frames of one episode never land
on both sides (neighbouring frames are near-duplicates, so a frame-level split would leak), and adding
episodes later never moves an existing one to the other side. The price: the validation share of a small
dataset is only near ``val_fraction`` (4 episodes at 0.25 may give 0, 1 or 2 validation episodes); pass
an explicit id list (``episodes=``) when the exact membership matters.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from typing import Literal

Split = Literal["train", "val", "all"]
SPLITS: tuple[str, ...] = ("train", "val", "all")


def split_position(episode_id: str, seed: int = 0) -> float:
    """Where ``episode_id`` falls in [0, 1) for ``seed``: the first 8 bytes of a SHA-256, scaled."""
    digest = hashlib.sha256(f"{seed}:{episode_id}".encode()).digest()
    return int.from_bytes(digest[:8], "big") / 2.0 ** 64


def split_of(episode_id: str, val_fraction: float = 0.1, seed: int = 0) -> Literal["train", "val"]:
    """The part (``"train"`` or ``"val"``) that ``episode_id`` belongs to."""
    if not 0.0 <= val_fraction <= 1.0:
        raise ValueError(f"val_fraction must be in [0, 1] (got {val_fraction!r})")
    return "val" if split_position(episode_id, seed) < val_fraction else "train"


def split_episode_ids(episode_ids: Iterable[str], val_fraction: float = 0.1, seed: int = 0) \
        -> tuple[list[str], list[str]]:
    """``(train_ids, val_ids)``, each sorted; disjoint, and together every id given."""
    train: list[str] = []
    val: list[str] = []
    for episode_id in sorted(set(episode_ids)):
        (val if split_of(episode_id, val_fraction, seed) == "val" else train).append(episode_id)
    return train, val


def check_split(split: str) -> None:
    if split not in SPLITS:
        raise ValueError(f"split must be one of {', '.join(SPLITS)} (got {split!r})")
