"""Versions: the package's and the on-disk format's.

The format version is code (not a string scattered through modules): readers compare against
``FORMAT_VERSION`` and refuse another major version with one clear message.
"""

from __future__ import annotations

__version__ = "0.2.0"

#: The episode format this package writes. Minor: additive, readers of the same major read it.
#: Major: an incompatible change; readers refuse majors they do not implement.
FORMAT_VERSION = "2.0"
FORMAT_MAJOR, FORMAT_MINOR = (int(p) for p in FORMAT_VERSION.split("."))
#: Majors this reader reads, with the newest minor of each it knows. A 1.x episode is a 2.x episode with
#: no residual-coded arrays and no ``pure_ref_rgb``, so the same reading code serves both.
READABLE_MAJORS: dict[int, int] = {1: 0, 2: FORMAT_MINOR}


def parse_format_version(text: str) -> tuple[int, int]:
    """Parse ``"MAJOR.MINOR"`` into two ints; raise ``ValueError`` naming what was received."""
    parts = str(text).split(".")
    if len(parts) != 2 or not all(p.isdigit() for p in parts):
        raise ValueError(f"format version must look like 'MAJOR.MINOR' (got {text!r})")
    return int(parts[0]), int(parts[1])


def check_readable(text: str, where: str) -> bool:
    """Raise ``FormatVersionError`` unless this reader reads format ``text``; ``where`` names the file.

    Returns True when the data is a newer minor version (readable; unknown additions are ignored).
    """
    from univtac_data.storage.errors import CorruptFileError, FormatVersionError

    try:
        major, minor = parse_format_version(text)
    except ValueError as error:
        raise CorruptFileError(f"{where}: {error}") from None
    if major not in READABLE_MAJORS:
        readable = " and ".join(f"{m}.x" for m in sorted(READABLE_MAJORS))
        raise FormatVersionError(
            f"{where}: written in format {text}; this reader (univtac-data {__version__}) reads format "
            f"{readable} only" + ("; upgrade univtac-data" if major > FORMAT_MAJOR else "")
        )
    return minor > READABLE_MAJORS[major]


def is_newer_minor(text: str) -> bool:
    """Whether ``text`` (a readable version) is a newer minor than this reader knows of its major."""
    major, minor = parse_format_version(text)
    return minor > READABLE_MAJORS.get(major, minor)
