"""Shared test setup: tests/ on sys.path for the factories, and headless defaults."""

import os
import pathlib
import sys
from typing import Any

import pytest

sys.path.insert(0, str(pathlib.Path(__file__).parent))
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture
def h5py_opens(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Every episode file opened with h5py from now on (any thread of this process)."""
    from univtac_data.storage.hdf5_store import HDF5Store

    opened: list[str] = []
    original = HDF5Store.open

    def counting(self: HDF5Store, loc: Any, relpath: str) -> Any:
        opened.append(relpath)
        return original(self, loc, relpath)

    monkeypatch.setattr(HDF5Store, "open", counting)
    return opened
