"""The validation report: per episode, per rule, pass / fail / skip with the offending frames and values.

JSON-safe by construction: non-finite values are stored as the strings ``"nan"``, ``"inf"``, ``"-inf"``.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from univtac_data.validators.config import ValidationConfig

Status = Literal["pass", "fail", "skip"]
Number = float | str  # str only for "nan", "inf", "-inf"

#: Version of the report's JSON shape; bump the major on an incompatible change.
REPORT_VERSION = "1.0"


def _json_number(value: float | int | str) -> Number:
    if isinstance(value, str):
        return value
    value = float(value)
    if math.isnan(value):
        return "nan"
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return value


class Finding(BaseModel):
    """One violation: where (field or file), which frames, which values, against which limit."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    message: str = Field(description="one line: what was expected and what was received")
    field: str | None = Field(default=None, description="array path, file or metadata key concerned")
    frames: list[int] = Field(default_factory=list, description="offending frame indices (first max_listed_frames)")
    values: list[Number] = Field(default_factory=list, description="the offending value at each listed frame")
    limits: list[Number] = Field(default_factory=list,
                                 description="per-frame limit when it varies by frame; empty when the rule's "
                                             "threshold applies")
    n_frames: int = Field(default=0, ge=0, description="how many frames offend in total")

    @field_validator("values", "limits", mode="before")
    @classmethod
    def _finite_or_text(cls, value: object) -> object:
        if isinstance(value, (list, tuple)):
            return [_json_number(v) for v in value]
        return value


class CheckResult(BaseModel):
    """The outcome of one rule on one episode (or on the dataset)."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    rule: str = Field(description="e.g. 'safety.max_indentation'")
    group: str = Field(description="'schema', 'safety' or 'physics'")
    status: Status
    threshold_name: str | None = Field(default=None, description="config or profile field compared against")
    threshold: Number | None = Field(default=None, description="its value, in the unit its name says")
    note: str = Field(default="", description="why a rule was skipped, or context for a pass")
    findings: list[Finding] = Field(default_factory=list)

    @field_validator("threshold", mode="before")
    @classmethod
    def _finite_or_text(cls, value: object) -> object:
        return None if value is None else _json_number(value)  # type: ignore[arg-type]

    @property
    def failed(self) -> bool:
        return self.status == "fail"


class EpisodeReport(BaseModel):
    """Every rule's result for one episode."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    episode_id: str
    path: str | None = Field(default=None, description="episode file or group, relative to the dataset root")
    n_frames: int | None = None
    checks: list[CheckResult] = Field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not any(c.failed for c in self.checks)

    def failed_checks(self) -> list[CheckResult]:
        return [c for c in self.checks if c.failed]

    def check(self, rule: str) -> CheckResult:
        """The result of ``rule``; KeyError when the rule did not run on this episode."""
        for result in self.checks:
            if result.rule == rule:
                return result
        raise KeyError(f"rule {rule!r} did not run on episode {self.episode_id}")


class Report(BaseModel):
    """A dataset's validation: dataset-level checks and one ``EpisodeReport`` per episode checked."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    report_version: str = REPORT_VERSION
    dataset: str = Field(description="path or URL validated")
    storage: str
    format_version: str
    validator_version: str
    groups: list[str]
    config: ValidationConfig
    dataset_checks: list[CheckResult] = Field(default_factory=list)
    episodes: dict[str, EpisodeReport] = Field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """True when every check of the dataset and of every episode holds."""
        return not any(c.failed for c in self.dataset_checks) and all(e.ok for e in self.episodes.values())

    def failed_episodes(self) -> list[str]:
        """Ids of episodes with at least one failing check, sorted: the ones training should skip."""
        return sorted(eid for eid, episode in self.episodes.items() if not episode.ok)

    def to_json(self, indent: int | None = 1) -> str:
        """The report as strict JSON (``ok`` and ``failed_episodes`` included for readers without this class)."""
        import json

        data = self.model_dump(mode="json")
        data["ok"] = self.ok
        data["failed_episodes"] = self.failed_episodes()
        return json.dumps(data, indent=indent, allow_nan=False)

    @classmethod
    def from_json(cls, text: str | bytes) -> Report:
        import json

        data = json.loads(text)
        data.pop("ok", None)
        data.pop("failed_episodes", None)
        return cls.model_validate(data)
