"""Loaders under DataLoader worker processes, on both storage backends."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest
import torch
from factories import assert_same, make_dataset

from univtac_data.loaders import PolicyChunkDataset, TactileFrameDataset


@pytest.fixture(scope="module", params=["hdf5", "zarr"])
def root(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_dataset(tmp_path_factory.mktemp(request.param) / "d", request.param, 3, n_frames=4,
                        cameras=("head",))


def batches(dataset: torch.utils.data.Dataset[Any], workers: int) -> list[dict[str, Any]]:
    loader = torch.utils.data.DataLoader(dataset, batch_size=5, shuffle=False, num_workers=workers)
    return list(loader)


class WorkerPids(torch.utils.data.Dataset[int]):
    """Which process read each item, and how many handles that process had opened by then."""

    def __init__(self, inner: TactileFrameDataset) -> None:
        self.inner = inner

    def __len__(self) -> int:
        return len(self.inner)

    def __getitem__(self, index: int) -> dict[str, int]:
        self.inner[index]
        return {"pid": os.getpid(), "opens": self.inner.reader.opens}


def test_frames_with_two_workers_match_one_process(root: Path) -> None:
    ds = TactileFrameDataset(root)
    ds[0]  # the parent now holds an open handle; workers must not read through a copy of it
    assert ds.reader.n_open == 1
    assert_same(batches(ds, 2), batches(ds, 0))


def test_channels_last_samples_collate_into_contiguous_batches(root: Path) -> None:
    # default_collate stacks into contiguous memory, in workers and in one process: same values as the default
    ds = TactileFrameDataset(root, compact=True, channels_last=True)
    assert ds[0]["marked_rgb"].movedim(0, -1).is_contiguous()
    assert_same(batches(ds, 2), batches(TactileFrameDataset(root, compact=True), 0))
    assert_same(batches(ds, 0), batches(TactileFrameDataset(root, compact=True), 0))


def test_each_worker_opens_its_own_handles(root: Path) -> None:
    ds = TactileFrameDataset(root, fields=["object_pose"])
    for k in range(0, len(ds), 8):  # the parent opens all 3 episodes before the workers fork
        ds[k]
    assert ds.reader.n_open == 3 and ds.reader.opens == 3
    seen = batches(WorkerPids(ds), 2)
    by_pid: dict[int, list[int]] = {}
    for batch in seen:
        for pid, opens in zip(batch["pid"], batch["opens"]):
            by_pid.setdefault(int(pid), []).append(int(opens))
    assert len(by_pid) == 2 and os.getpid() not in by_pid
    # a worker's first item finds no inherited handle: it opens one itself, and never more than the 3 episodes
    assert all(counts[0] == 1 and max(counts) <= 3 for counts in by_pid.values())
    assert ds.reader.opens == 3


def test_policy_with_two_workers_matches_one_process(root: Path) -> None:
    ds = PolicyChunkDataset(root, obs_keys=["robot/ee_pose", "scene/cameras/head/rgb", "tactile/right/marked_rgb"],
                            history=2, chunk=3, normalize="min_max")
    ds[5]
    out = batches(ds, 2)
    assert_same(out, batches(ds, 0))
    assert out[0]["obs"]["tactile/right/marked_rgb"].shape == (5, 2, 3, 240, 320)
    assert out[0]["action_is_pad"].shape == (5, 3)


def test_several_datasets_and_split_with_workers(tmp_path: Path) -> None:
    a = make_dataset(tmp_path / "a", "hdf5", 4, n_frames=2)
    b = make_dataset(tmp_path / "b", "zarr", 4, n_frames=2)
    train = TactileFrameDataset([a, b], split="train", val_fraction=0.5, fields=["object_pose"])
    val = TactileFrameDataset([a, b], split="val", val_fraction=0.5, fields=["object_pose"])
    keys = {split: {(int(d), e) for batch in batches(ds, 2) for d, e in zip(batch["dataset"], batch["episode_id"])}
            for split, ds in (("train", train), ("val", val))}
    assert not keys["train"] & keys["val"]
    assert keys["train"] | keys["val"] == {(d, f"ep{k}") for d in (0, 1) for k in range(4)}
    assert len(train) + len(val) == 2 * 4 * 2 * 2
