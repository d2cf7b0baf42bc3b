"""The loaders check each episode's dtypes and shapes against the schema when they open it (values are for
``univtac-data validate``), and name a missing index instead of finding no episode."""

from __future__ import annotations

import numpy as np
import pytest
from factories import make_dataset
from test_validate_support import STORAGES, replace_array

from univtac_data.loaders import TactileFrameDataset
from univtac_data.storage import CorruptFileError, DatasetError


@pytest.mark.parametrize("storage", STORAGES)
def test_a_wrong_dtype_is_refused_on_open_naming_the_file(tmp_path, storage):
    root = make_dataset(tmp_path / "ds", storage, 2, n_frames=3)
    replace_array(root, storage, "ep1", "tactile/left/depth_um", np.zeros((3, 240, 320), np.float64))
    with pytest.raises(CorruptFileError, match=r"ep1\.(h5|zarr): tactile/left/depth_um is stored as float64, "
                                               r"the format says uint16"):
        TactileFrameDataset(root)


@pytest.mark.parametrize("storage", STORAGES)
def test_a_wrong_marker_shape_is_refused_on_open(tmp_path, storage):
    root = make_dataset(tmp_path / "ds", storage, 1, n_frames=3)
    with pytest.raises(CorruptFileError, match=r"tactile/left/markers_px has shape \(3, 5, 2\)"):
        replace_array(root, storage, "ep0", "tactile/left/markers_px", np.zeros((3, 5, 2), np.float32))
        TactileFrameDataset(root)


def test_nan_passes_the_loader_check_values_are_validates_job(tmp_path):
    root = make_dataset(tmp_path / "ds", "hdf5", 1, n_frames=3)
    markers = np.full((3, 63, 2), np.nan, np.float32)
    replace_array(root, "hdf5", "ep0", "tactile/left/markers_px", markers)
    assert len(TactileFrameDataset(root)) > 0  # documented: the loader checks layouts, not values


def test_a_missing_index_is_named(tmp_path):
    root = make_dataset(tmp_path / "ds", "hdf5", 2, n_frames=3)
    (root / "meta/episodes.parquet").unlink()
    with pytest.raises(DatasetError, match=r"episodes.parquet: the dataset's index is missing; rebuild it with "
                                           r"'univtac-data reindex "):
        TactileFrameDataset(root)
