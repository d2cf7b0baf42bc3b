"""univtac-data: a versioned episode format, CPU generators, validators and PyTorch loaders for
visuo-tactile robot data.

The data flow: ``univtac_data.schema`` (the format as code) -> ``univtac_data.generators`` (make episodes)
-> ``univtac_data.storage`` (write and read them) -> ``univtac_data.validators`` (gate them) ->
``univtac_data.loaders`` (train on them).


The names below import on first use (PEP 562), so that ``univtac-data`` starts without loading h5py, zarr and
Arrow before it has parsed its arguments (and Ctrl-C during start-up ends it with one line).
"""

from __future__ import annotations

import importlib
from typing import Any

from univtac_data.version import FORMAT_VERSION, __version__

_HOMES = {
    "Episode": "univtac_data.episode", "EpisodeError": "univtac_data.episode", "check_episode": "univtac_data.episode",
    "content_hash": "univtac_data.episode",
    **{name: "univtac_data.schema" for name in ("FIELDS", "SENSORS", "CameraInfo", "DatasetInfo", "EpisodeMeta",
                                                 "GeneratorInfo", "SafetySummary", "SensorProfile", "get_sensor")},
    **{name: "univtac_data.storage" for name in ("CorruptFileError", "Dataset", "DatasetError", "DatasetWriter",
                                                  "FormatVersionError", "NotADatasetError")},
}

__all__ = [
    "FIELDS", "FORMAT_VERSION", "SENSORS", "CameraInfo", "CorruptFileError", "Dataset", "DatasetError",
    "DatasetInfo", "DatasetWriter", "Episode", "EpisodeError", "EpisodeMeta", "FormatVersionError",
    "GeneratorInfo", "NotADatasetError", "SafetySummary", "SensorProfile", "__version__", "check_episode",
    "content_hash", "get_sensor",
]


def __getattr__(name: str) -> Any:
    if name in _HOMES:
        value = getattr(importlib.import_module(_HOMES[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'univtac_data' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
