"""The spec in spec/ is generated from the code; this fails when they drift. The JSON Schemas validate
what the writer stores."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import jsonschema
from factories import make_dataset

from univtac_data.schema.export import generated_files
from univtac_data.schema.fields import FIELDS

SPEC = Path(__file__).resolve().parents[1] / "spec"


def test_committed_spec_files_match_the_models():
    for rel, content in generated_files().items():
        committed = (SPEC / rel).read_text() if (SPEC / rel).exists() else None
        assert committed == content, (
            f"spec/{rel} is out of date with the code: run 'python -m univtac_data.schema.export'"
        )


def test_stored_documents_validate_against_the_published_schemas(tmp_path):
    root = make_dataset(tmp_path / "ds", "hdf5", 1, cameras=("head",))
    schema = json.loads((SPEC / "schema/episode_meta.schema.json").read_text())
    with h5py.File(root / "episodes/ep0.h5", "r") as f:
        meta = json.loads(f.attrs["univtac_meta"])
    jsonschema.validate(meta, schema)
    jsonschema.validate(json.loads((root / "meta/info.json").read_text()),
                        json.loads((SPEC / "schema/dataset_info.schema.json").read_text()))
    jsonschema.validate(json.loads((root / "meta/manifest.json").read_text()),
                        json.loads((SPEC / "schema/manifest.schema.json").read_text()))
    bad = dict(meta, kind="cooking")
    try:
        jsonschema.validate(bad, schema)
    except jsonschema.ValidationError:
        pass
    else:
        raise AssertionError("the schema accepted kind='cooking'")


def test_the_prose_spec_covers_every_field_and_file():
    prose = (SPEC / "format.md").read_text()
    for spec in FIELDS:
        leaf = spec.path.rsplit("/", 1)[-1]
        assert leaf in prose, f"spec/format.md does not mention {spec.path}"
    for name in ("meta/info.json", "meta/episodes.parquet", "meta/manifest.json", "Versioning", "fields.md"):
        assert name in prose
