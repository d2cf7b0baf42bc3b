"""The README's commands are the ones CI runs, and its Python example works."""

from __future__ import annotations

import re
from pathlib import Path

from factories import make_dataset

ROOT = Path(__file__).resolve().parents[1]


def _bash_blocks() -> list[str]:
    return re.findall(r"```bash\n(.*?)\n```", (ROOT / "README.md").read_text(), flags=re.S)


def test_ci_runs_the_readme_test_command():
    blocks = _bash_blocks()
    test_command = next(b for b in blocks if "pytest" in b).strip()
    ci = (ROOT / ".ci/run").read_text().splitlines()
    assert test_command in ci, ".ci/run must run the README's test command verbatim"


def test_readme_python_examples_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    make_dataset(tmp_path / "out/indenters", "hdf5", 4, n_frames=12)  # stands in for the generated corpus
    from univtac_data import DatasetWriter
    from univtac_data.generators.tasks.base import TaskConfig
    from univtac_data.generators.tasks.collect import TaskEpisodeSpec, run_expert

    demo = run_expert(TaskEpisodeSpec("lift_can", 0, TaskConfig(camera_size=(32, 24)))).episode
    assert demo is not None
    DatasetWriter.open(tmp_path / "out/lift_can").add(demo)  # stands in for `generate task lift_can`
    examples = re.findall(r"```python\n(.*?)\n```", (ROOT / "README.md").read_text(), flags=re.S)
    assert examples
    for _run in range(2):  # the examples run twice (a rerun must not fail: no EpisodeExistsError)
        for example in examples:
            exec(compile(example, "README.md", "exec"), {})
    assert (tmp_path / "out/copy/episodes/ep0.zarr").is_dir()
