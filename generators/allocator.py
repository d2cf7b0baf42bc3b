"""Keep freed memory in the process: the generator allocates and frees the same large arrays every frame.

glibc's malloc serves blocks above its mmap threshold (128 KiB to start) with fresh ``mmap`` calls and gives
them back on ``free``, and trims the heap top when it is freed; the next frame's arrays then fault their pages
in again, one by one. A tactile frame makes a few dozen such arrays (images, depth, their float temporaries),
so the page faults cost about 7 % of a generated frame and most of stacking an episode's frames
(``benchmarks/generate_throughput.py``). Raising the mmap and trim thresholds keeps those pages mapped and
reused. The price is that the process keeps its peak heap (a few hundred MB per worker).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import sys
from collections.abc import Callable

__all__ = ["fix_mmap_threshold", "keep_freed_memory"]

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # mallopt parameter numbers (glibc malloc.h)
_MMAP_THRESHOLD_BYTES = 32 << 20  # glibc's largest accepted value on 64-bit: whole-episode stacks still mmap
_TRIM_THRESHOLD_BYTES = 1 << 30


@functools.cache
def _mallopt() -> Callable[[int, int], int] | None:
    """glibc's ``mallopt``, or None where the C library is not glibc (macOS, musl)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        mallopt = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").mallopt
    except (OSError, AttributeError):
        return None
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return mallopt  # type: ignore[no-any-return]


@functools.cache
def keep_freed_memory() -> bool:
    """Tune glibc's allocator for this process (once); True when applied, False elsewhere (macOS, musl)."""
    mallopt = _mallopt()
    if mallopt is None:
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_BYTES)) and bool(mallopt(_M_TRIM_THRESHOLD,
                                                                                 _TRIM_THRESHOLD_BYTES))


def fix_mmap_threshold(nbytes: int) -> bool:
    """The opposite trade: serve every allocation above ``nbytes`` from its own mapping, returned to the system
    when freed, and stop glibc from raising that threshold as large blocks are freed. For a process that frees
    large temporaries between small blocks it keeps (reading a training set into memory), where the adaptive
    threshold would move the temporaries onto the heap and never give them back. True when applied."""
    mallopt = _mallopt()
    return mallopt is not None and bool(mallopt(_M_MMAP_THRESHOLD, nbytes))
