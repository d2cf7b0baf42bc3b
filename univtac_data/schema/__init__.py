"""Schema: sensor profiles, the field table and the metadata models (the format, as code)."""

from univtac_data.schema.fields import FIELDS, FIELDS_BY_PATH, FieldSpec, expand_paths, field_for_path
from univtac_data.schema.models import (
    ACTION_NAMES,
    PAD_NAMES,
    CameraInfo,
    DatasetInfo,
    EpisodeMeta,
    GeneratorInfo,
    IndexRow,
    Manifest,
    ManifestEntry,
    SafetySummary,
)
from univtac_data.schema.sensors import SENSORS, Light, Material, Optics, SensorProfile, get_sensor

__all__ = [
    "ACTION_NAMES", "FIELDS", "FIELDS_BY_PATH", "PAD_NAMES", "SENSORS", "CameraInfo", "DatasetInfo",
    "EpisodeMeta", "FieldSpec", "GeneratorInfo", "IndexRow", "Light", "Manifest", "ManifestEntry", "Material",
    "Optics", "SafetySummary", "SensorProfile", "expand_paths", "field_for_path", "get_sensor",
]
