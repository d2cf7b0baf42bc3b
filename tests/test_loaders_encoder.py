"""The reference encoder: model shapes and loss terms, and the training script end to end (2 steps)."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType

import torch

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def load(name: str) -> ModuleType:
    """Import ``examples/<name>.py`` (examples are scripts, not a package)."""
    if name in sys.modules:
        return sys.modules[name]
    if str(EXAMPLES) not in sys.path:
        sys.path.insert(0, str(EXAMPLES))
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up here
    spec.loader.exec_module(module)
    return module


def test_encoder_outputs_and_loss_weights() -> None:
    enc = load("univtac_encoder")
    model = enc.UniVTACEncoder(40, 56, n_markers=63)
    with torch.no_grad():
        pred = model(torch.rand(2, 3, 40, 56))
    assert pred["features"].shape == (2, 512)
    assert pred["marked_rgb"].shape == pred["pure_rgb"].shape == (2, 3, 40, 56)
    assert pred["depth_mm"].shape == (2, 1, 40, 56) and pred["markers"].shape == (2, 63, 2)
    assert pred["object_pose"].shape == (2, 7)
    assert 0 <= float(pred["pure_rgb"].min()) and float(pred["pure_rgb"].max()) <= 1
    target = dict(pred)
    target["depth_mm"] = pred["depth_mm"] + 2.0  # contact term: MSE 4, from depth only
    target["object_pose"] = pred["object_pose"] + 1.0  # pose term: MSE 1
    losses = enc.univtac_loss(pred, target)
    assert abs(float(losses["shape"])) < 1e-12
    assert abs(float(losses["contact"]) - 4.0) < 1e-5 and abs(float(losses["pose"]) - 1.0) < 1e-5
    assert abs(float(losses["total"]) - (0.5 * 4.0 + 0.5 * 1.0)) < 1e-5


def test_train_encoder_script_end_to_end(tmp_path: Path) -> None:
    script = load("train_encoder")
    figure, out = tmp_path / "recon.png", tmp_path / "result.json"
    result = script.main(["--demo", "--demo-dir", str(tmp_path / "demo"), "--demo-shapes", "2",
                          "--demo-episodes", "2", "--demo-frames", "3", "--steps", "2", "--batch-size", "4",
                          "--image-size", "32", "48", "--workers", "0", "--probe-steps", "3", "--log-every", "1",
                          "--figure", str(figure), "--out-json", str(out)])
    assert figure.stat().st_size > 10_000
    saved = json.loads(out.read_text())
    assert saved["steps"] == 2 and saved["shapes"] == ["shape0", "shape1"]
    assert set(saved["held_out_episodes"]).isdisjoint(saved["train_episodes"])
    assert len(saved["held_out_episodes"]) == 2  # one per shape
    for label in ("trained", "random_init"):
        assert 0.0 <= saved["probe_accuracy"][label] <= 1.0
    assert saved["probe_accuracy"]["chance"] == 0.5
    assert result["loss_last"]["total"] > 0
