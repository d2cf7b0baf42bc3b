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


def kill_mid_episode(root: Path, storage: str, log: Path) -> bool:
    """Start a writer and SIGKILL it as soon as one episode is complete and the next is being written; whether
    the kill landed while a partial episode was on disk (the writer may rename it in between)."""
    proc = start_writer(root, storage, log)
    episodes = root / "episodes"
    deadline = time.monotonic() + 120
    killed = False
    while time.monotonic() < deadline and proc.poll() is None:
        names = os.listdir(episodes) if episodes.exists() else []
        done = [n for n in names if not n.startswith(".tmp-")]
        if done and any(n.startswith(".tmp-") for n in names):
            os.kill(proc.pid, signal.SIGKILL)
            killed = True
            break
        time.sleep(0.002)
    proc.wait(timeout=30)
    assert killed, f"writer finished or failed before it could be killed: {log.read_text()}"
    assert proc.returncode == -signal.SIGKILL
    return any(n.startswith(".tmp-") for n in os.listdir(episodes))


@pytest.mark.parametrize("storage", ["hdf5", "zarr"])
def test_sigkill_mid_episode_then_resume(tmp_path, storage):
    # the poll and the kill race the writer's rename: try again (on a fresh dataset) until a partial episode is left
    for attempt in range(5):
        root = tmp_path / f"ds{attempt}"
        if kill_mid_episode(root, storage, tmp_path / f"first{attempt}.log"):
            break
    else:
        pytest.fail("in 5 attempts the kill never landed while a partial episode was on disk")
    episodes = root / "episodes"

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
