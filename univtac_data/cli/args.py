"""Argument types shared by the subcommands: each refuses bad input with a one-line argparse error."""

from __future__ import annotations

import argparse
import os

from univtac_data.storage.errors import DatasetError


def positive_int(text: str) -> int:
    """An integer of at least 1 (workers, episodes, counts)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive integer (got {text!r})") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer (got {value})")
    return value


def camera_size(text: str) -> tuple[int, int]:
    """``WxH`` in pixels, each side 16 to 4096, e.g. 480x270."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be WxH in pixels, e.g. 480x270 (got {text!r})") from None
    if not (16 <= w <= 4096 and 16 <= h <= 4096):
        raise argparse.ArgumentTypeError(f"must be between 16 and 4096 px a side (got {text!r})")
    return w, h


def check_output_file(path: str, flag: str) -> None:
    """Fail before any work when ``path`` (the value of option ``flag``) cannot be written: a directory, or no
    write access where it goes. Folders on the way that do not exist yet are fine (the writer makes them)."""
    target = os.path.abspath(path)
    if os.path.isdir(target):
        raise DatasetError(f"{path}: is a directory; give a file name for {flag}")
    if os.path.exists(target):
        if not os.access(target, os.W_OK):
            raise DatasetError(f"{path}: cannot write here (permission denied)")
        return
    _check_folder(path, os.path.dirname(target))


def check_output_dir(path: str, flag: str) -> None:
    """Fail before any work when the folder ``path`` (the value of option ``flag``) cannot be written into: a
    file of that name, or no write access where it goes. Folders that do not exist yet are fine."""
    target = os.path.abspath(path)
    if os.path.exists(target) and not os.path.isdir(target):
        raise DatasetError(f"{path}: is a file; give a folder for {flag}")
    _check_folder(path, target)


def _check_folder(path: str, folder: str) -> None:
    # the nearest existing one of ``folder`` and its parents must be a folder we may write into
    while not os.path.exists(folder):
        folder = os.path.dirname(folder)
    if not os.path.isdir(folder):
        raise DatasetError(f"{path}: cannot write here ({folder} is not a directory)")
    if not os.access(folder, os.W_OK):
        raise DatasetError(f"{path}: cannot write here (permission denied)")
