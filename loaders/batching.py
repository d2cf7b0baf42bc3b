"""``SensorBatchSampler``: batches drawn from one sensor at a time, for datasets that mix sensors.

Samples of different sensors differ in image size and marker count (gf225 480 x 480 with 81 markers,
gelsight_mini 240 x 320 with 63), so ``default_collate`` cannot stack them. This batch sampler shuffles
each sensor's samples, cuts them into batches, and shuffles the order of the batches, so every batch is
one sensor and an epoch still visits every sample once.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Protocol

import numpy as np
import torch


class HasSensors(Protocol):
    def __len__(self) -> int: ...

    def sensor_of(self, index: int) -> str: ...


class SensorBatchSampler(torch.utils.data.Sampler[list[int]]):
    """Yields lists of sample indices, each list from a single sensor.

    ``dataset``: anything with ``__len__`` and ``sensor_of(index)`` (``TactileFrameDataset``);
    ``drop_last``: drop each sensor's last short batch; ``seed``: the shuffle of epoch e uses seed + e
    (call ``set_epoch``), so runs repeat exactly.
    """

    def __init__(self, dataset: HasSensors, batch_size: int, *, shuffle: bool = True, drop_last: bool = False,
                 seed: int = 0) -> None:
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1 (got {batch_size})")
        self.batch_size, self.shuffle, self.drop_last, self.seed = batch_size, shuffle, drop_last, seed
        self.epoch = 0
        groups: dict[str, list[int]] = {}
        for index in range(len(dataset)):
            groups.setdefault(dataset.sensor_of(index), []).append(index)
        self.groups = {sensor: np.asarray(ids, np.int64) for sensor, ids in sorted(groups.items())}

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def _batches(self) -> list[np.ndarray]:
        rng = np.random.default_rng(self.seed + self.epoch)
        batches = []
        for ids in self.groups.values():
            order = rng.permutation(ids) if self.shuffle else ids
            cut = len(order) - len(order) % self.batch_size if self.drop_last else len(order)
            batches.extend(order[k:k + self.batch_size] for k in range(0, cut, self.batch_size))
        if self.shuffle:
            batches = [batches[k] for k in rng.permutation(len(batches))]
        return batches

    def __iter__(self) -> Iterator[list[int]]:
        for batch in self._batches():
            yield batch.tolist()

    def __len__(self) -> int:
        return len(self._batches())
