"""Every rough edge a new user met (issue 21, item 5): one line and a non-zero exit instead of a traceback, nothing
half-written, damaged episodes skipped and reported, progress in logs, help with examples, `list`."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest
from factories import make_dataset

from univtac_data import Dataset

ROOT = Path(__file__).resolve().parents[1]
TINY = ("--shapes", "cone", "--episodes-per-shape", "1", "--frames-per-episode", "3", "--workers", "1")


def cli(*args: str, timeout: float = 300, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "univtac_data.cli.main", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd, env={**os.environ, "MUJOCO_GL": "egl"})


def python(code: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout)


def one_line_error(done: subprocess.CompletedProcess[str], code: int = 2) -> str:
    assert done.returncode == code, done.stderr
    assert "Traceback" not in done.stderr, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    return lines[0]


def usage_error(done: subprocess.CompletedProcess[str]) -> str:
    """argparse's bad usage: exit 2, its usage lines, then one error line."""
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    return done.stderr.strip().splitlines()[-1]


# --- one line instead of a traceback -----------------------------------------------------------------------------

def test_unwritable_outputs_are_one_line_and_leave_nothing(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    src = make_dataset(tmp_path / "src", "hdf5", 1, n_frames=3)
    out = str(blocker / "ds")
    assert "cannot create the dataset folder (Not a directory)" in \
        one_line_error(cli("generate", "indenters", "--out", out, *TINY))
    assert "cannot create the dataset folder" in one_line_error(cli("convert", str(src), out, "--to", "zarr"))
    assert "a-file is not a directory" in one_line_error(cli("preview", str(src), "--out", str(blocker / "x.png")))
    assert "is a directory" in one_line_error(cli("preview", str(src), "--out", str(tmp_path)))
    # the output is itself a file: named as such, not as a lock that cannot be made inside it
    assert one_line_error(cli("generate", "indenters", "--out", str(blocker), *TINY)).endswith(
        f"{blocker}: is a file, not a dataset folder")
    assert "is a file, not a dataset folder" in one_line_error(cli("convert", str(src), str(blocker), "--to", "zarr"))
    assert blocker.read_text() == "not a folder"


def test_a_folder_that_is_not_a_dataset_is_left_as_it_was(tmp_path):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine/notes.txt").write_text("keep")
    line = one_line_error(cli("generate", "indenters", "--out", str(tmp_path / "mine"), *TINY))
    assert "directory is not empty and holds no univtac-data dataset" in line
    assert sorted(p.name for p in (tmp_path / "mine").iterdir()) == ["notes.txt"]  # no lock file, no meta/


@pytest.mark.skipif(importlib.util.find_spec("s3fs") is not None, reason="s3fs is installed")
def test_an_object_store_url_without_its_package_names_the_extra():
    line = one_line_error(cli("info", "s3://bucket/dataset"))
    assert line == ("univtac-data: error: s3://bucket/dataset: reading s3:// URLs needs a package that is not "
                    "installed; pip install 'univtac-data[s3]'")


def test_an_unsupported_url_scheme_is_one_line():
    assert "foo://x: unsupported URL scheme foo://" in one_line_error(cli("validate", "foo://x"))


def test_ctrl_c_during_start_up_is_one_line():
    code = ("import importlib, sys\n"
            "real = importlib.import_module\n"
            "def slow(name, *a, **k):\n"
            "    if name == 'univtac_data.cli.convert':\n"
            "        raise KeyboardInterrupt\n"
            "    return real(name, *a, **k)\n"
            "importlib.import_module = slow\n"
            "from univtac_data.cli.main import main\n"
            "sys.exit(main(['info', 'x']))\n")
    assert one_line_error(python(code), 130) == "univtac-data: interrupted"


# --- values that make no sense -----------------------------------------------------------------------------------

@pytest.mark.parametrize("value", ["0", "-2"])
def test_workers_and_counts_must_be_positive(tmp_path, value):
    assert "argument --workers: must be a positive integer" in \
        usage_error(cli("generate", "indenters", "--out", str(tmp_path / "ds"), "--workers", value))
    assert not (tmp_path / "ds").exists()
    src = make_dataset(tmp_path / "src", "hdf5", 1, n_frames=3)
    assert "argument --max-episodes: must be a positive integer" in \
        usage_error(cli("preview", str(src), "--gallery", "--max-episodes", value, "--out", str(tmp_path / "g.png")))
    assert not (tmp_path / "g.png").exists()


@pytest.mark.parametrize("value", ["0", "nan", "inf", "-50"])
def test_a_rate_that_is_not_a_positive_number_of_hz_is_one_line(tmp_path, value):
    """``--rate nan`` made the indenter corpus loop forever and ``--rate inf`` a traceback; the tasks' ``--rate 0``
    divided by zero."""
    out = tmp_path / "ds"
    assert "--rate must be a positive number of Hz" in \
        one_line_error(cli("generate", "indenters", "--out", str(out), "--rate", value, *TINY, timeout=60))
    # the tasks say "not a whole number of 2 ms control ticks" for inf
    expected = "not a whole number of 2 ms control ticks" if value == "inf" else "must be a positive number of Hz"
    line = one_line_error(cli("generate", "task", "lift_can", "--episodes", "1", "--out", str(out), "--rate", value))
    assert line.startswith("univtac-data: error: --rate: rate") and expected in line
    line = one_line_error(cli("evaluate", "lift_can", "--policy", "zero", "--rate-hz", value))
    assert line.startswith("univtac-data: error: --rate-hz: rate") and expected in line
    assert not out.exists()


def test_convert_onto_its_own_source_is_refused(tmp_path):
    src = make_dataset(tmp_path / "src", "hdf5", 2, n_frames=3)
    before = sorted(p.name for p in src.rglob("*"))
    for dst in (str(src), str(src) + "/", os.path.relpath(src)):
        line = one_line_error(cli("convert", str(src), dst, "--to", "hdf5"))
        assert "the destination is the source dataset; choose a new folder" in line
    assert sorted(p.name for p in src.rglob("*")) == before


def test_validate_unknown_episode_is_bad_usage(tmp_path):
    src = make_dataset(tmp_path / "src", "hdf5", 2, n_frames=3)
    line = one_line_error(cli("validate", str(src), "--episodes", "nope"))
    assert "--episodes: no episode 'nope' in the index (episodes: ep0, ep1)" in line


# --- silent wrong answers ----------------------------------------------------------------------------------------

def test_convert_rerun_says_it_skipped(tmp_path):
    src = make_dataset(tmp_path / "src", "hdf5", 2, n_frames=3)
    first = cli("convert", str(src), str(tmp_path / "z"), "--to", "zarr")
    assert first.returncode == 0 and "2 converted, 0 already converted, 0 failed" in first.stdout, first.stderr
    again = cli("convert", str(src), str(tmp_path / "z"), "--to", "zarr")
    assert again.returncode == 0 and "0 converted, 2 already converted, 0 failed" in again.stdout, again.stderr


# --- Ray ---------------------------------------------------------------------------------------------------------

def test_ray_executor_without_ray_leaves_nothing(tmp_path):
    code = ("import sys\n"
            "class NoRay:\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name == 'ray' or name.startswith('ray.'):\n"
            "            raise ModuleNotFoundError(name, name=name)\n"
            "sys.meta_path.insert(0, NoRay())\n"
            "from univtac_data.cli.main import main\n"
            f"sys.exit(main(['generate', 'indenters', '--out', {str(tmp_path / 'ds')!r}, '--executor', 'ray']))\n")
    line = one_line_error(python(code))
    assert line == "univtac-data: error: --executor ray needs Ray: pip install 'univtac-data[ray]'"
    assert not (tmp_path / "ds").exists()  # no stray meta/info.json


def test_an_unreachable_ray_address_fails_within_a_timeout(tmp_path):
    done = cli("generate", "indenters", "--out", str(tmp_path / "ds"), "--executor", "ray", "--ray-address",
               "127.0.0.1:1", timeout=60)
    assert "--ray-address 127.0.0.1:1: no Ray cluster answers there" in one_line_error(done)
    assert not (tmp_path / "ds").exists()


# --- one damaged episode does not abort the rest -----------------------------------------------------------------

def test_preview_gallery_skips_a_damaged_episode(tmp_path):
    src = make_dataset(tmp_path / "src", "hdf5", 3, n_frames=3)
    (src / "episodes/ep1.h5").write_bytes(b"junk")
    done = cli("preview", str(src), "--gallery", "--out", str(tmp_path / "g.png"))
    assert done.returncode == 1 and "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines() == [
        f"skipped: {src}/episodes/ep1.h5: not a readable HDF5 file (Unable to synchronously open file (file "
        f"signature not found))"]
    assert (tmp_path / "g.png").stat().st_size > 0


# --- progress, help, list ----------------------------------------------------------------------------------------

def test_progress_is_printed_as_plain_lines_when_stderr_is_not_a_terminal(tmp_path):
    done = cli("generate", "indenters", "--out", str(tmp_path / "ds"), *TINY)
    assert done.returncode == 0, done.stderr
    assert done.stderr.splitlines()[-1].startswith("generate: 1/1 episodes (100 %); frames_per_s ")
    assert "\r" not in done.stderr


def test_every_command_has_a_description_and_examples():
    for command in (["--help"], ["generate", "--help"], ["generate", "indenters", "--help"], ["validate", "--help"],
                    ["info", "--help"], ["convert", "--help"], ["reindex", "--help"], ["preview", "--help"],
                    ["list", "--help"]):
        done = cli(*command)
        assert done.returncode == 0 and "examples:\n  univtac-data " in done.stdout, command
        assert len(done.stdout.split("\n\n")) >= 3, command  # usage, description, options (and examples)


def test_list_prints_the_names_other_commands_accept():
    from univtac_data.generators.indenters.shapes import INDENTER_NAMES
    from univtac_data.schema.sensors import SENSORS

    assert cli("list", "shapes", "--names").stdout.split() == list(INDENTER_NAMES)
    sensors = cli("list", "sensors").stdout.splitlines()
    assert [line.split()[0] for line in sensors] == list(SENSORS) and "GelSight Mini" in sensors[0]
    tasks = cli("list", "tasks")
    assert tasks.returncode == 0, tasks.stderr
    if importlib.util.find_spec("univtac_data.generators.tasks") is None:
        assert tasks.stdout == "(no tasks)\n"
    else:
        assert tasks.stdout.strip()


# --- docs --------------------------------------------------------------------------------------------------------

def test_relative_links_in_the_docs_resolve():
    import re

    broken = []
    for doc in [ROOT / "README.md", ROOT / "CHANGELOG.md", *(ROOT / "docs").glob("*.md"), *(ROOT / "spec").glob("*.md")]:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", doc.read_text()):
            if "://" in target or target.startswith("mailto:"):
                continue
            if not (doc.parent / target).exists():
                broken.append(f"{doc.relative_to(ROOT)} -> {target}")
    assert not broken, broken


def test_convert_finishes_a_partial_conversion_and_says_so(tmp_path):
    import shutil

    src = make_dataset(tmp_path / "src", "hdf5", 2, n_frames=3)
    assert cli("convert", str(src), str(tmp_path / "z"), "--to", "zarr").returncode == 0
    shutil.rmtree(tmp_path / "z/episodes/ep1.zarr")  # as if killed before ep1 was written
    assert cli("reindex", str(tmp_path / "z")).returncode == 0
    done = cli("convert", str(src), str(tmp_path / "z"), "--to", "zarr")
    assert done.returncode == 0 and "1 converted, 1 already converted, 0 failed" in done.stdout, done.stderr
    assert Dataset.open(tmp_path / "z").episode_ids == ["ep0", "ep1"]


@pytest.mark.parametrize("rate", [0.0, -1.0, float("nan"), float("inf")])
def test_the_simulation_refuses_a_recording_rate_it_would_never_reach(rate):
    """Below the CLI: a NaN rate made the indenter episode loop forever; the simulation's config refuses it."""
    from univtac_data.generators.scene.sim import SimConfig

    with pytest.raises(ValueError, match="record_rate_hz must be a positive number of Hz"):
        SimConfig(record_rate_hz=rate)
    assert SimConfig(record_rate_hz=None).record_rate_hz is None
