"""A real writer process killed with SIGKILL mid-episode leaves a readable dataset of complete episodes,
and a second run completes it."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from factories import make_episode

from univtac_data import Dataset, content_hash

N_EPISODES = 6
WRITER = """
import sys
sys.path.insert(0, {tests!r})
from factories import make_episode
from univtac_data import DatasetWriter
writer = DatasetWriter.open({root!r}, storage={storage!r})
for k in range({n}):
    if not writer.has(f"ep{{k}}"):
        writer.add(make_episode("gelsight_mini", 40, f"ep{{k}}", seed=k))
"""


def expected(k: int) -> str:
    return content_hash(make_episode("gelsight_mini", 40, f"ep{k}", seed=k))


def start_writer(root: Path, storage: str, log: Path) -> subprocess.Popen[bytes]:
    code = WRITER.format(tests=str(Path(__file__).parent), root=str(root), storage=storage, n=N_EPISODES)
    with open(log, "wb") as stderr:
        return subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.DEVNULL, stderr=stderr)


@pytest.mark.parametrize("storage", ["hdf5", "zarr"])
def test_sigkill_mid_episode_then_resume(tmp_path, storage):
    root = tmp_path / "ds"
    proc = start_writer(root, storage, tmp_path / "first.log")
    episodes = root / "episodes"
    deadline = time.monotonic() + 120
    killed_mid_episode = False
    while time.monotonic() < deadline and proc.poll() is None:
        names = os.listdir(episodes) if episodes.exists() else []
        done = [n for n in names if not n.startswith(".tmp-")]
        if done and any(n.startswith(".tmp-") for n in names):
            os.kill(proc.pid, signal.SIGKILL)
            killed_mid_episode = True
            break
        time.sleep(0.002)
    proc.wait(timeout=30)
    assert killed_mid_episode, f"writer finished or failed before it could be killed: {(tmp_path / 'first.log').read_text()}"
    assert proc.returncode == -signal.SIGKILL
    assert any(n.startswith(".tmp-") for n in os.listdir(episodes)), "the kill did not land mid-episode"

    ds = Dataset.open(root)
    assert 1 <= len(ds) < N_EPISODES
    for eid in ds.episode_ids:
        assert content_hash(ds.load_episode(eid)) == expected(int(eid[2:]))
    assert ds.verify_checksums() == []

    rerun = start_writer(root, storage, tmp_path / "second.log")
    assert rerun.wait(timeout=300) == 0, (tmp_path / 'second.log').read_text()
    ds = Dataset.open(root)
    assert ds.episode_ids == [f"ep{k}" for k in range(N_EPISODES)]
    for eid in ds.episode_ids:
        assert content_hash(ds.load_episode(eid)) == expected(int(eid[2:]))
    assert ds.verify_checksums() == []
    assert not [n for n in os.listdir(episodes) if n.startswith(".tmp-")]
