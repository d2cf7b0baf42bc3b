"""Errors a user can cause with bad input. Each message is one line and names the file."""

from __future__ import annotations


class DatasetError(Exception):
    """Base class: ``str(error)`` is the one line the CLI prints."""


class NotADatasetError(DatasetError):
    """The path exists but holds no univtac-data dataset (no ``meta/info.json``)."""


class DatasetNotFoundError(DatasetError):
    """The path does not exist."""


class FormatVersionError(DatasetError):
    """The data was written in a major format version this reader does not read."""


class CorruptFileError(DatasetError):
    """A file is unreadable, truncated, fails its checksum, or holds content that contradicts the spec."""


class EpisodeExistsError(DatasetError):
    """An episode id is written twice."""
