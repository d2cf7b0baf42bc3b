"""What every benchmark script records beside its numbers: the machine they ran on."""

from __future__ import annotations

import importlib.metadata
import os
import platform
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
FIGURES = ROOT / "docs" / "figures"


def machine(threads_used: int | None = None, packages: tuple[str, ...] = ("numpy", "scipy", "mujoco")) \
        -> dict[str, Any]:
    """CPU model, core count, Python and package versions."""
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    info: dict[str, Any] = {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version()}
    if threads_used is not None:
        info["threads_used"] = threads_used
    for name in packages:
        info[name] = importlib.metadata.version(name)
    try:
        info["load_average_1min_at_start"] = os.getloadavg()[0]
    except OSError:
        pass
    return info
