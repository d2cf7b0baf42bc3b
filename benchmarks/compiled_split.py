"""CPU time inside compiled code, for the benchmarks that split a frame into compiled work and the Python
between it (``task_throughput.py --split``, ``generate_throughput.py --split``).

Every compiled entry point the generator and the writer call from Python is wrapped: this package's numba
kernels, MuJoCo's ``mj_*`` functions and its model compiler, SciPy's FFTs and Blosc's compression. Only the
outermost call is timed, so a kernel that calls another counts once. Everything else is Python: the
interpreter, NumPy's array calls, h5py, and the timers themselves (two clock reads a call). NumPy and h5py
count as Python on purpose: a rewrite could avoid some of their work, so the compiled seconds stay a lower
bound on what a frame needs, and frames / compiled seconds is a *ceiling* rate that no rewrite of the Python
could beat without the kernels doing less work.
"""

from __future__ import annotations

import functools
import inspect
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import mujoco
import numcodecs.blosc
import scipy.fft
from numba.core.registry import CPUDispatcher

FFT_FUNCTIONS = ("fft", "ifft", "rfft", "irfft", "fft2", "ifft2", "rfft2", "irfft2")


class CompiledClock:
    """CPU seconds inside wrapped compiled calls, filed under ``key()`` at the time of the call (a stage
    name, say; default: one key, "all")."""

    def __init__(self, key: Callable[[], str] = lambda: "all") -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self._key = key
        self._inside = False
        self._replaced: list[tuple[Any, str, Any]] = []  # (owner, attribute, original) for uninstall()

    def wrap(self, function: Callable[..., Any]) -> Callable[..., Any]:
        clock = self

        @functools.wraps(function)
        def call(*args: Any, **kwargs: Any) -> Any:
            if clock._inside:
                return function(*args, **kwargs)
            clock._inside = True
            start = time.process_time()
            try:
                return function(*args, **kwargs)
            finally:
                clock.seconds[clock._key()] += time.process_time() - start
                clock._inside = False

        return call

    def _replace(self, owner: Any, attr: str, value: Any) -> None:
        self._replaced.append((owner, attr, inspect.getattr_static(owner, attr)))  # a class's staticmethod as is
        setattr(owner, attr, value)

    def install(self) -> int:
        """Wrap every compiled entry point (module docstring); the number wrapped. Call it after a first frame
        or episode has loaded every module and kernel; ``uninstall()`` puts the originals back."""
        for name, module in list(sys.modules.items()):
            if not name.startswith("univtac_data") or module is None:
                continue
            for attr, value in list(vars(module).items()):
                if isinstance(value, CPUDispatcher):
                    self._replace(module, attr, self.wrap(value))
        for attr in dir(mujoco):
            if attr.startswith("mj_") and callable(getattr(mujoco, attr)):
                self._replace(mujoco, attr, self.wrap(getattr(mujoco, attr)))
        # building a scene is compiled work too (MuJoCo's model compiler), once an episode
        self._replace(mujoco.MjModel, "from_xml_string", staticmethod(self.wrap(mujoco.MjModel.from_xml_string)))
        for attr in FFT_FUNCTIONS:
            self._replace(scipy.fft, attr, self.wrap(getattr(scipy.fft, attr)))
        self._replace(numcodecs.blosc, "compress", self.wrap(numcodecs.blosc.compress))
        return len(self._replaced)

    def uninstall(self) -> None:
        """Put back every original ``install()`` wrapped."""
        while self._replaced:
            owner, attr, original = self._replaced.pop()
            setattr(owner, attr, original)
