"""`univtac-data evaluate`: policies, seeds disjoint from generation, errors reported per rollout."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

from univtac_data.envs.evaluate import evaluate, wilson_interval
from univtac_data.generators.tasks.base import EVAL_SEED_BASE

os.environ.setdefault("MUJOCO_GL", "egl")


def cli(*args: str, pythonpath: str | None = None) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "MUJOCO_GL": "egl"}
    if pythonpath:
        env["PYTHONPATH"] = pythonpath + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-m", "univtac_data.cli.main", *args], capture_output=True, text=True,
                          timeout=600, env=env)


def test_wilson_interval_matches_the_closed_form():
    assert wilson_interval(0, 0) == (0.0, 1.0)
    lo, hi = wilson_interval(95, 100)
    assert lo == pytest.approx(0.8882, abs=1e-3) and hi == pytest.approx(0.9785, abs=1e-3)
    lo, hi = wilson_interval(0, 10)
    assert lo == 0.0 and hi == pytest.approx(0.2775, abs=1e-3)
    # all successes: the interval ends at exactly 1 (a chart's error bar must not come out negative)
    assert wilson_interval(300, 300)[1] == 1.0 and wilson_interval(100, 100) == (pytest.approx(0.963, abs=1e-3), 1.0)


def test_expert_succeeds_and_zero_does_not_on_evaluation_seeds():
    expert = evaluate("lift_can", "expert", episodes=3, env_kwargs={"cameras": False}, progress=False)
    assert expert.successes == 3 and all(r.seed >= EVAL_SEED_BASE for r in expert.rollouts)
    assert [r.seed for r in expert.rollouts] == [EVAL_SEED_BASE + k for k in range(3)]
    zero = evaluate("lift_can", "zero", episodes=2, env_kwargs={"cameras": False}, progress=False)
    assert zero.successes == 0 and all(r.reason == "step_limit" for r in zero.rollouts)


def test_user_policies_that_fail_are_reported_and_the_evaluation_goes_on(tmp_path):
    (tmp_path / "my_policies.py").write_text(textwrap.dedent("""
        import numpy as np

        class Wrong:
            def reset(self): pass
            def act(self, obs): return np.zeros(3)

        class Nan:
            def reset(self): pass
            def act(self, obs): return np.full(8, np.nan)

        class Hold:
            def reset(self): pass
            def act(self, obs): return obs["agent_pos"]

        def wrong(): return Wrong()
        def nan(): return Nan()
        def hold(): return Hold()
        def not_a_policy(): return 42
    """))
    out = tmp_path / "wrong.json"
    wrong = cli("evaluate", "lift_can", "--policy", "my_policies:wrong", "--episodes", "2", "--no-cameras",
                "--json", str(out), pythonpath=str(tmp_path))
    assert wrong.returncode == 0, wrong.stderr
    report = json.loads(out.read_text())
    assert report["rollouts"] == 2 and report["errors"] == 2 and report["success_rate"] == 0.0
    assert "shape (3,)" in report["per_rollout"][0]["reason"] and "shape (3,)" in wrong.stderr
    nan = cli("evaluate", "lift_can", "--policy", "my_policies:nan", "--episodes", "1", "--no-cameras",
              pythonpath=str(tmp_path))
    assert nan.returncode == 0 and "non-finite" in nan.stderr
    hold = cli("evaluate", "lift_can", "--policy", "my_policies:hold", "--episodes", "1", "--no-cameras",
               pythonpath=str(tmp_path))
    assert hold.returncode == 0 and "success 0/1" in hold.stdout and "Wilson" in hold.stdout
    bad = cli("evaluate", "lift_can", "--policy", "my_policies:not_a_policy", "--episodes", "1",
              pythonpath=str(tmp_path))
    assert bad.returncode == 2 and "reset() and act(obs)" in bad.stderr
    missing = cli("evaluate", "lift_can", "--policy", "no_such_module:make", "--episodes", "1")
    assert missing.returncode == 2 and "cannot import 'no_such_module'" in missing.stderr
    assert len(missing.stderr.strip().splitlines()) == 1
    unknown = cli("evaluate", "no_task", "--policy", "expert")
    assert unknown.returncode == 2 and "unknown task" in unknown.stderr


def test_video_of_the_first_rollouts(tmp_path):
    pytest.importorskip("av")
    from univtac_data.export.video import read_mp4

    report = evaluate("lift_can", "zero", episodes=2, env_kwargs={"camera_size": (64, 48)}, video_dir=str(tmp_path),
                      videos=1, progress=False)
    files = sorted(p.name for p in tmp_path.iterdir())
    assert files == [f"lift_can-{EVAL_SEED_BASE}.mp4"]
    frames = read_mp4(str(tmp_path / files[0]))
    assert frames.shape[0] == report.rollouts[0].steps + 1 and frames.shape[1] % 2 == 0


def test_outputs_that_cannot_be_written_are_refused_before_any_rollout(tmp_path):
    """--json naming a folder and --video naming a file were found only after the rollouts (a traceback) or
    made every rollout fail as if the policy had; both are now one line before anything runs, and --json
    into folders not made yet works."""
    (tmp_path / "a_file").write_text("x")
    (tmp_path / "a_folder").mkdir()
    for args, message in [
        (["--json", str(tmp_path / "a_folder")], "is a directory; give a file name for --json"),
        (["--json", str(tmp_path / "a_file" / "r.json")], "is not a directory"),
        (["--video", str(tmp_path / "a_file")], "is a file; give a folder for --video"),
    ]:
        result = cli("evaluate", "lift_can", "--policy", "expert", "--episodes", "1", "--no-cameras", *args)
        assert result.returncode == 2, (args, result.stderr)
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and message in lines[0] and not result.stdout, (args, result.stderr)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "a_folder"]
    assert not list((tmp_path / "a_folder").iterdir())

    nested = tmp_path / "new" / "sub" / "r.json"
    result = cli("evaluate", "lift_can", "--policy", "zero", "--episodes", "1", "--no-cameras", "--json", str(nested))
    assert result.returncode == 0, result.stderr
    assert len(json.loads(nested.read_text())["per_rollout"]) == 1
