"""The data path installs and runs without torch: generate (indenters and tasks), validate, info, convert,
reindex, preview, list and evaluate, in a fresh interpreter where importing torch fails as it does when the
package is not installed."""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# a meta-path finder that makes `import torch` (and any torch submodule) fail like a missing package
NO_TORCH = """
import sys
class _NoTorch:
    def find_spec(self, name, path=None, target=None):
        if name == "torch" or name.startswith("torch."):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None
sys.meta_path.insert(0, _NoTorch())
"""


def without_torch(code: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", NO_TORCH + code], capture_output=True, text=True, timeout=600,
                          cwd=cwd, env={**__import__("os").environ, "MUJOCO_GL": "egl"})


def cli_without_torch(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    code = ("from univtac_data.cli.main import main\n"
            f"code = main({list(args)!r})\n"
            "assert 'torch' not in sys.modules\n"
            "sys.exit(code)\n")
    return without_torch(code, cwd)


def test_the_main_job_runs_without_torch(tmp_path):
    blocked = without_torch("import torch", tmp_path)
    assert blocked.returncode == 1 and "No module named 'torch'" in blocked.stderr  # the blocker works
    steps = [
        ("generate", "indenters", "--shapes", "cone", "--episodes-per-shape", "1", "--frames-per-episode", "3",
         "--workers", "1"),
        ("validate", "out/indenters"),
        ("info", "out/indenters"),
        ("convert", "out/indenters", "out/z", "--to", "zarr"),
        ("reindex", "out/z"),
        ("preview", "out/z", "--gallery", "--out", "gallery.png"),
        ("preview", "out/indenters", "--out", "sheet.png", "--frames", "2"),
        ("list", "shapes"),
        ("generate", "task", "lift_can", "--episodes", "1", "--camera-size", "32x24", "--workers", "1",
         "--out", "out/lift_can"),
        ("validate", "out/lift_can"),
        ("evaluate", "lift_can", "--policy", "replay:out/lift_can", "--no-cameras"),
    ]
    for step in steps:
        done = cli_without_torch(tmp_path, *step)
        assert done.returncode == 0, (step, done.stderr[-2000:])
    assert (tmp_path / "gallery.png").stat().st_size > 0 and (tmp_path / "sheet.png").stat().st_size > 0


def test_the_loaders_name_the_extra_when_torch_is_missing(tmp_path):
    done = without_torch("import univtac_data.loaders", tmp_path)
    assert done.returncode == 1
    last = done.stderr.strip().splitlines()[-1]
    assert last == ("ModuleNotFoundError: univtac_data.loaders needs PyTorch, which is not installed: "
                    "pip install 'univtac-data[torch]' (or [train])"), done.stderr


def test_torch_is_an_extra_pulled_in_by_test_and_train():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert not [d for d in project["dependencies"] if re.match(r"torch\b", d)]
    extras = project["optional-dependencies"]
    assert extras["torch"] == ["torch>=2.3"]
    assert "univtac-data[torch]" in extras["test"] and "univtac-data[torch]" in extras["train"]


def test_readme_installs_the_main_job_without_torch_and_the_tests_with_the_pin():
    blocks = re.findall(r"```bash\n(.*?)\n```", (ROOT / "README.md").read_text(), flags=re.S)
    main, tests = blocks[0], next(b for b in blocks if "pytest" in b)
    assert "torch" not in main and "pip install -e . &&" in main
    assert tests.index("pip install torch==2.13.0") < tests.index("pip install -e \".[test]\"")
    ignored = (ROOT / ".gitignore").read_text().splitlines()
    assert ".venv/" in ignored and "/out/" in ignored
