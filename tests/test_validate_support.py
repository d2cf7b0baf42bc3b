"""Helpers shared by the validator tests: write hand-broken episodes, edit stored files. (No tests here.)"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path

import h5py
import numpy as np
import zarr
from factories import make_episode

from univtac_data import Episode, SafetySummary
from univtac_data.storage import DatasetWriter
from univtac_data.validators import Report

STORAGES = ("hdf5", "zarr")
SUFFIX = {"hdf5": ".h5", "zarr": ".zarr"}


def refresh_safety(episode: Episode) -> Episode:
    """Recompute meta.safety from the arrays, so that only the rule a test targets is broken."""
    pads = episode.meta.pads

    def finite_max(name: str) -> float:  # a summary holds finite numbers; the arrays may not
        values = np.concatenate([episode[f"tactile/{p}/{name}"].astype(np.float64).ravel() for p in pads])
        return max(0.0, float(values[np.isfinite(values)].max(initial=0.0)))

    episode.meta = episode.meta.model_copy(update={"safety": SafetySummary(
        max_indentation_mm=max(float(episode[f"tactile/{p}/depth_um"].max()) for p in pads) / 1000.0,
        max_slip_mm=finite_max("slip_mm"), max_normal_force_n=finite_max("normal_force_n"),
    )})
    return episode


def write_dataset(root: Path, episodes: Iterable[Episode], storage: str = "hdf5") -> Path:
    writer = DatasetWriter.open(root, storage=storage)
    for episode in episodes:
        writer.add(episode)
    return root


def clean_and_broken(root: Path, broken: Episode, storage: str = "hdf5") -> Path:
    """A dataset holding a clean ``ep0`` and the test's ``broken`` episode (id ``ep1``)."""
    return write_dataset(root, [make_episode("gelsight_mini", broken.meta.n_frames, "ep0", seed=5), broken],
                         storage)


def failing(report: Report, episode_id: str) -> set[str]:
    return {c.rule for c in report.episodes[episode_id].failed_checks()}


def episode_path(root: Path, storage: str, episode_id: str) -> Path:
    return Path(root) / "episodes" / f"{episode_id}{SUFFIX[storage]}"


def episode_files(root: Path, storage: str, episode_id: str) -> list[Path]:
    """Every file of an episode (one for HDF5, many for Zarr), sorted."""
    path = episode_path(root, storage, episode_id)
    if path.is_file():
        return [path]
    return sorted(Path(d) / f for d, _, files in os.walk(path) for f in files)


def replace_array(root: Path, storage: str, episode_id: str, path: str, array: np.ndarray | None) -> None:
    """Replace (or, with None, delete) one stored array of an episode, bypassing the writer's checks."""
    target = episode_path(root, storage, episode_id)
    if storage == "hdf5":
        with h5py.File(target, "r+") as handle:
            if path in handle:
                del handle[path]
            if array is not None:
                handle.create_dataset(path, data=array)
        return
    group = zarr.open_group(zarr.storage.LocalStore(str(target)), mode="r+", zarr_format=3)
    if path in group:
        del group[path]
    if array is not None:
        group.create_array(name=path, shape=array.shape, dtype=array.dtype)[...] = array


def edit_meta(root: Path, storage: str, episode_id: str, **changes: object) -> None:
    """Edit the stored metadata JSON (HDF5 root attribute / Zarr group attribute ``univtac_meta``); a new
    ``format_version`` goes to the file's own ``format_version`` attribute too, as a writer of it would."""
    target = episode_path(root, storage, episode_id)
    if storage == "hdf5":
        with h5py.File(target, "r+") as handle:
            meta = json.loads(handle.attrs["univtac_meta"])
            meta.update(changes)
            handle.attrs["univtac_meta"] = json.dumps(meta)
    else:
        group = zarr.open_group(zarr.storage.LocalStore(str(target)), mode="r+", zarr_format=3)
        meta = dict(group.attrs["univtac_meta"])  # type: ignore[arg-type]
        meta.update(changes)
        group.attrs["univtac_meta"] = meta
    if "format_version" in changes:
        set_version_attr(root, storage, episode_id, str(changes["format_version"]))


def set_version_attr(root: Path, storage: str, episode_id: str, value: str | None) -> None:
    """Set (or with None delete) the episode file's own ``format_version`` attribute."""
    target = episode_path(root, storage, episode_id)
    if storage == "hdf5":
        with h5py.File(target, "r+") as handle:
            if value is None:
                del handle.attrs["format_version"]
            else:
                handle.attrs["format_version"] = value
        return
    group = zarr.open_group(zarr.storage.LocalStore(str(target)), mode="r+", zarr_format=3)
    attrs = dict(group.attrs)
    if value is None:
        attrs.pop("format_version")
    else:
        attrs["format_version"] = value
    group.attrs.clear()
    group.attrs.update(attrs)


def flip_byte(path: Path, offset: int, xor: int = 0xFF) -> None:
    data = bytearray(path.read_bytes())
    data[offset % len(data)] ^= xor
    path.write_bytes(bytes(data))


def hdf5_chunk_offset(root: Path, episode_id: str, path: str, frame: int) -> int:
    """Byte offset in the file of the chunk holding ``frame`` of a one-frame-per-chunk HDF5 array."""
    with h5py.File(episode_path(root, "hdf5", episode_id), "r") as handle:
        dataset = handle[path]
        info = dataset.id.get_chunk_info_by_coord((frame,) + (0,) * (dataset.ndim - 1))
        return int(info.byte_offset) + int(info.size) // 2
