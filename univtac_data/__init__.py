"""univtac-data: a versioned episode format, CPU generators, validators and PyTorch loaders for
visuo-tactile robot data.

The data flow: ``univtac_data.schema`` (the format as code) -> ``univtac_data.generators`` (make episodes)
-> ``univtac_data.storage`` (write and read them) -> ``univtac_data.validators`` (gate them) ->
``univtac_data.loaders`` (train on them).
"""

from univtac_data.episode import Episode, EpisodeError, check_episode, content_hash
from univtac_data.schema import (
    FIELDS,
    SENSORS,
    CameraInfo,
    DatasetInfo,
    EpisodeMeta,
    GeneratorInfo,
    SafetySummary,
    SensorProfile,
    get_sensor,
)
from univtac_data.storage import (
    CorruptFileError,
    Dataset,
    DatasetError,
    DatasetWriter,
    FormatVersionError,
    NotADatasetError,
)
from univtac_data.version import FORMAT_VERSION, __version__

__all__ = [
    "FIELDS", "FORMAT_VERSION", "SENSORS", "CameraInfo", "CorruptFileError", "Dataset", "DatasetError",
    "DatasetInfo", "DatasetWriter", "Episode", "EpisodeError", "EpisodeMeta", "FormatVersionError",
    "GeneratorInfo", "NotADatasetError", "SafetySummary", "SensorProfile", "__version__", "check_episode",
    "content_hash", "get_sensor",
]
