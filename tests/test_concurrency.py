"""Nothing lost under concurrency and faults: one writer per dataset, index writes that keep every entry, workers
that die with their parent, resume that checks every episode, and `info` that looks at the files."""

from __future__ import annotations

import fcntl
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from factories import make_dataset, make_episode

from univtac_data import Dataset
from univtac_data.generators.indenters.corpus import IndenterEpisodeSpec
from univtac_data.generators.runner import run_corpus
from univtac_data.storage import DatasetError, DatasetLock, DatasetLockedError, DatasetWriter, LockHolder
from univtac_data.storage.lock import LOCK_NAME

TINY = ("--shapes", "cone,sphere", "--episodes-per-shape", "2", "--frames-per-episode", "3", "--workers", "1")


def cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "univtac_data.cli.main", *args], capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, "MUJOCO_GL": "egl"})


def start(*args: str, quiet: bool = False) -> subprocess.Popen[str]:
    pipe = subprocess.DEVNULL if quiet else subprocess.PIPE
    return subprocess.Popen([sys.executable, "-m", "univtac_data.cli.main", *args], stdout=pipe, stderr=pipe,
                            text=True, env={**os.environ, "MUJOCO_GL": "egl"})


def dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def assert_each_episode_indexed_once(root: Path, expected: set[str]) -> None:
    dataset = Dataset.open(root)  # read_index refuses an id listed twice
    assert set(dataset.index) == expected
    on_disk = {p.name.removesuffix(".h5") for p in (root / "episodes").iterdir()}
    assert on_disk == expected  # no temporaries, no unindexed file
    assert dataset.verify_checksums() == []
    assert not (root / LOCK_NAME).exists()  # every writer released its lock


# --- the writer lock ---------------------------------------------------------------------------------------------

def test_a_second_writer_is_refused_in_one_line_naming_the_holder(tmp_path):
    root = make_dataset(tmp_path / "ds", "hdf5", 1)
    before = sorted(p.name for p in (root / "meta").iterdir())
    with DatasetLock(root):
        for args in (("generate", "indenters", "--out", str(root), *TINY),
                     ("convert", str(tmp_path / "other"), str(root), "--to", "hdf5"),
                     ("reindex", str(root))):
            if args[0] == "convert":
                make_dataset(tmp_path / "other", "hdf5", 1)
            done = cli(*args)
            assert done.returncode == 2, done.stderr
            lines = done.stderr.strip().splitlines()
            assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
            assert f"another writer is using this dataset: pid {os.getpid()} on {socket.gethostname()}" in lines[0]
    assert sorted(p.name for p in (root / "meta").iterdir()) == before
    assert Dataset.open(root).episode_ids == ["ep0"]
    assert not (root / LOCK_NAME).exists()  # released: a dataset carries no lock file between writers


def test_a_writer_refused_before_the_holder_named_itself_still_names_it(tmp_path):
    # the holder takes the flock first and writes its pid just after: a writer refused in between must wait for
    # the name rather than say "nobody" (a race seen in CI with two writers started at once)
    root = tmp_path / "ds"
    root.mkdir()
    fd = os.open(root / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o644)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    holder = LockHolder(pid=4242, host=socket.gethostname(), started="now", command="univtac-data generate")
    late = threading.Timer(0.3, lambda: os.pwrite(fd, holder.to_bytes(), 0))
    late.start()
    try:
        with pytest.raises(DatasetLockedError, match="another writer is using this dataset: pid 4242 on "):
            DatasetLock(root).acquire()
    finally:
        late.join()
        os.close(fd)


def test_a_stale_lock_is_taken_over_and_named(tmp_path):
    root = make_dataset(tmp_path / "ds", "hdf5", 1)
    pid = dead_pid()
    (root / LOCK_NAME).write_bytes(LockHolder(pid=pid, host=socket.gethostname(), started="then",
                                              command="univtac-data generate").to_bytes())
    done = cli("reindex", str(root))
    assert done.returncode == 0, done.stderr
    assert f"took over a stale lock of pid {pid} on {socket.gethostname()}" in done.stderr


def test_the_lock_is_shared_within_a_process_and_freed_with_the_writer(tmp_path):
    first = DatasetWriter.open(tmp_path / "ds")
    second = DatasetWriter.open(tmp_path / "ds")  # same process: shares the hold
    first.close()
    probe = "from univtac_data.storage import DatasetLock; DatasetLock({!r}).acquire()".format(str(tmp_path / "ds"))
    held = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert held.returncode == 1 and "DatasetLockedError" in held.stderr
    del second  # a forgotten writer frees the dataset when it goes away
    free = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert free.returncode == 0, free.stderr


def test_an_object_store_lock_is_a_conditional_create(tmp_path):
    url = "memory://univtac-lock-test/ds"
    with DatasetLock(url):
        import univtac_data.storage.lock as lock_module

        holds = dict(lock_module._HELD)
        lock_module._HELD.clear()  # look like another process
        try:
            with pytest.raises(DatasetLockedError, match=f"pid {os.getpid()} on .*remove memory://"):
                DatasetLock(url).acquire()
        finally:
            lock_module._HELD.update(holds)
    again = DatasetLock(url).acquire()  # released: the lock object is gone
    assert again.held
    again.release()


def test_two_writers_started_at_once_index_every_episode_exactly_once(tmp_path):
    root = tmp_path / "ds"
    procs = [start("generate", "indenters", "--out", str(root), *TINY) for _ in range(2)]
    results = [(p.wait(timeout=600), *p.communicate()) for p in procs]
    codes = sorted(code for code, _out, _err in results)
    assert codes in ([0, 0], [0, 2]), results
    for code, _out, err in results:
        if code == 2:  # refused cleanly: one line naming the holder
            assert len(err.strip().splitlines()) == 1 and "another writer is using this dataset: pid" in err, err
    expected = {f"gelsight_mini-{shape}-{k:04d}" for shape in ("cone", "sphere") for k in range(2)}
    assert_each_episode_indexed_once(root, expected)


def test_writers_without_the_lock_keep_each_others_index_entries(tmp_path):
    root = tmp_path / "ds"
    a = DatasetWriter.open(root, lock=False)
    b = DatasetWriter.open(root, lock=False)
    a.add(make_episode(episode_id="ep0"))
    b.add(make_episode(episode_id="ep1"))  # b read the index before ep0 was committed
    a.add(make_episode(episode_id="ep2"))
    assert_each_episode_indexed_once(root, {"ep0", "ep1", "ep2"})


# --- workers die with their parent -------------------------------------------------------------------------------

def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("executor", ["local", "ray"])
def test_sigkill_of_the_generate_parent_ends_its_workers(tmp_path, executor):
    if executor == "ray":
        pytest.importorskip("ray")
    from univtac_data.generators.reaper import descendants

    root = tmp_path / "ds"
    started: set[int] = set()
    parent = start("generate", "indenters", "--out", str(root), "--episodes-per-shape", "4", "--frames-per-episode",
                   "60", "--workers", "2", "--executor", executor, quiet=True)
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and parent.poll() is None:
            started |= set(descendants(parent.pid))
            # local: two pool workers and the resource tracker; ray: wait for the first finished episode
            if (executor == "local" and len(started) >= 3) or \
                    (executor == "ray" and (root / "episodes").is_dir() and any((root / "episodes").iterdir())):
                break
            time.sleep(0.2)
        assert parent.poll() is None and len(started) >= 3, f"workers never started ({parent.poll()})"
        time.sleep(1.0)  # the workers are busy in an episode
        started |= set(descendants(parent.pid))
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=30)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and any(_alive(c) for c in started):
            time.sleep(0.2)
        assert not [c for c in started if _alive(c)], "processes outlived their generate parent"
    finally:
        if parent.poll() is None:
            parent.kill()
        for child in started:  # a failed run must not leave them behind
            if _alive(child):
                os.kill(child, signal.SIGKILL)


# --- resume and info check every episode -------------------------------------------------------------------------

def test_resume_checks_every_finished_episode_and_info_reports_the_mix(tmp_path):
    root = str(tmp_path / "ds")
    assert run_corpus(root, [IndenterEpisodeSpec("gelsight_mini", "cone", 0, frames=3)], progress=False).written == 1
    assert run_corpus(root, [IndenterEpisodeSpec("gelsight_mini", "sphere", 0, frames=4)], progress=False).written == 1
    both = [IndenterEpisodeSpec("gelsight_mini", shape, 0, frames=3) for shape in ("cone", "sphere")]
    with pytest.raises(DatasetError, match=r"sphere-0000.h5: made with frames=4, this run asks for frames=3"):
        run_corpus(root, both, progress=False)  # the first finished episode (cone) agrees: not enough
    done = cli("info", root)
    assert done.returncode == 1
    assert "indenter episodes disagree on n_frames: 3 (1 episode), 4 (1 episode)" in done.stderr


def test_info_checks_every_indexed_file_against_the_manifest(tmp_path):
    root = make_dataset(tmp_path / "ds", "hdf5", 3)
    ok = cli("info", str(root))
    assert ok.returncode == 0 and ok.stderr == "", ok.stderr
    (root / "episodes/ep0.h5").unlink()
    with open(root / "episodes/ep1.h5", "r+b") as handle:
        handle.truncate(1000)
    done = cli("info", str(root))
    assert done.returncode == 1 and "Traceback" not in done.stderr
    warnings = done.stderr.strip().splitlines()
    assert len(warnings) == 2, done.stderr
    assert warnings[0].startswith("warning: ") and "ep0.h5: indexed but the file is missing" in warnings[0]
    assert "ep1.h5: 1000 bytes, the manifest says" in warnings[1]
    assert "episodes        3" in done.stdout  # the summary still prints


def test_info_warns_when_the_index_is_missing(tmp_path):
    root = make_dataset(tmp_path / "ds", "zarr", 2)
    (root / "meta/episodes.parquet").unlink()
    done = cli("info", str(root))
    assert done.returncode == 1
    assert done.stderr.strip() == (f"warning: {root}/meta/episodes.parquet: the index is missing (2 episode files on "
                                   f"disk); run 'univtac-data reindex {root}'")
