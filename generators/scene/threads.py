"""One BLAS thread while simulating: the same seed gives the same bytes in every process.

OpenBLAS splits a large matrix-vector product (the tactile shear solve on a contact across the whole pad)
over its threads, and the partial sums then add up in another order: 1e-9 N differences between a process
with two BLAS threads and a Ray worker with one (Ray sets ``OMP_NUM_THREADS=1``). Simulation runs with one
BLAS thread everywhere; switching costs about 8 us (threadpoolctl, the library scikit-learn uses for this).
"""

from __future__ import annotations

import functools
from contextlib import AbstractContextManager

from threadpoolctl import ThreadpoolController


@functools.cache
def _controller() -> ThreadpoolController:
    # made on first use, once numpy's and scipy's BLAS libraries are loaded
    import scipy.fft  # noqa: F401
    import scipy.linalg  # noqa: F401

    return ThreadpoolController()


def one_blas_thread() -> AbstractContextManager[object]:
    """A context in which every loaded BLAS library uses one thread."""
    return _controller().limit(limits=1, user_api="blas")


__all__ = ["one_blas_thread"]
