"""Argument types shared by the subcommands: each refuses bad input with a one-line argparse error."""

from __future__ import annotations

import argparse


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
