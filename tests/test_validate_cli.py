"""``univtac-data validate``: exit codes, table and JSON output, one-line errors."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

import numpy as np
import pytest
from factories import make_dataset, make_episode
from test_validate_support import clean_and_broken, refresh_safety

from univtac_data.cli import validate as cli


def run_cli(*argv: str) -> int:
    parser = argparse.ArgumentParser(prog="univtac-data")
    cli.add_parser(parser.add_subparsers(dest="command"))
    return cli.run(parser.parse_args(["validate", *argv]))


@pytest.fixture(scope="module")
def clean_root(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("cli") / "clean", storage="hdf5", n_episodes=2, n_frames=3)


@pytest.fixture(scope="module")
def broken_root(tmp_path_factory):
    episode = make_episode("gelsight_mini", 3, "ep1", seed=1)
    episode["tactile/right/slip_mm"][2] = 4.0
    refresh_safety(episode)
    return clean_and_broken(tmp_path_factory.mktemp("cli") / "broken", episode)


def test_clean_dataset_exits_0_with_a_table(clean_root, capsys):
    assert run_cli(str(clean_root)) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[-1].startswith("OK: 0 of 2 episode(s) failed, 6 frames checked")
    assert "ep0" in out and "ep1" in out


def test_failing_episode_exits_1_and_names_the_rule(broken_root, capsys):
    assert run_cli(str(broken_root)) == 1
    out = capsys.readouterr().out
    line = next(row for row in out.splitlines() if row.startswith("ep1"))
    assert "FAIL" in line and "safety.slip_while_held" in line
    assert "tactile/right/slip_mm: 1 frame(s)" in out


def test_json_output(broken_root, capsys):
    assert run_cli(str(broken_root), "--json", "--groups", "safety,physics") == 1
    data = json.loads(capsys.readouterr().out)
    assert data["failed_episodes"] == ["ep1"] and data["groups"] == ["safety", "physics"]


def test_episode_and_group_selection(broken_root, capsys):
    assert run_cli(str(broken_root), "--episodes", "ep0") == 0
    assert run_cli(str(broken_root), "--groups", "physics") == 0  # slip is a safety matter
    capsys.readouterr()


@pytest.mark.parametrize("setup", ["missing", "empty", "bad_info", "newer_major"])
def test_unusable_input_exits_2_with_one_line(tmp_path, clean_root, capsys, setup):
    path = tmp_path / "ds"
    if setup == "empty":
        path.mkdir()
    elif setup == "bad_info":
        (path / "meta").mkdir(parents=True)
        (path / "meta" / "info.json").write_text("[1, 2")
    elif setup == "newer_major":
        import shutil

        shutil.copytree(clean_root, path)
        info = json.loads((path / "meta" / "info.json").read_text())
        (path / "meta" / "info.json").write_text(json.dumps({**info, "format_version": "3.0"}))
    assert run_cli(str(path)) == 2
    err = capsys.readouterr().err
    assert err.startswith("univtac-data: error: ") and str(path) in err and err.count("\n") == 1


def test_bad_arguments_are_refused(clean_root, capsys):
    for argv in (["--groups", "chemistry"], ["--workers", "0"], ["--episodes", ","]):
        with pytest.raises(SystemExit) as exit_info:
            run_cli(str(clean_root), *argv)
        assert exit_info.value.code == 2
    capsys.readouterr()


def test_module_entry_point_with_workers(tmp_path):
    root = make_dataset(tmp_path / "ds", storage="zarr", n_episodes=2, n_frames=3)
    (root / "episodes" / "ep1.zarr" / "timestamps_ns" / "c" / "0").write_bytes(np.zeros(7, np.uint8).tobytes())
    done = subprocess.run([sys.executable, "-m", "univtac_data.cli.validate", str(root), "--json", "--workers", "2"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 1, done.stderr
    data = json.loads(done.stdout)
    assert data["failed_episodes"] == ["ep1"]
    # no bar when stderr is not a terminal: plain progress lines for a log, ending with the total (a slow run also
    # prints the lines its interval passed)
    lines = done.stderr.splitlines()
    assert lines[-1] == "validate: 2/2 episodes (100 %)", done.stderr
    assert set(lines[:-1]) <= {"validate: 1/2 episodes (50 %)"}, done.stderr
