"""``univtac-data preview``'s views of task episodes: ``--gallery`` tiles show the scene camera beside the pad
at the expert's first correction made in touch; an episode's contact sheet spreads its frames over those where
the pad touches."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
from factories import make_episode

from univtac_data import Dataset
from univtac_data.cli.preview import _dataset_frames, _gallery_tiles, recorded_corrections
from univtac_data.export.episode_video import resize_to_height
from univtac_data.storage import DatasetWriter

N_FRAMES = 5  # the factory's pads touch from frame 1 on, equally deep in every frame


def task_dataset(root: Path) -> Path:
    """ep0: a task whose first correction (frame 0) is made before the pads touch and whose second is at
    frame 3; ep1: a task without corrections; ep2: an indenter press without cameras."""
    writer = DatasetWriter.open(root, storage="hdf5", sensors=["gelsight_mini"])
    corrected = make_episode(n_frames=N_FRAMES, episode_id="ep0", seed=0, kind="task", name="lift_can",
                             cameras=("head", "wrist"))
    corrected.meta.extra = {"task": {"memory": {"corrections": [
        {"what": "look before touching", "signal": "head camera", "step": 0},
        {"what": "grasp squareness", "signal": "contact patch depth gradient", "step": 3, "dx_mm": 1.5}]}}}
    writer.add(corrected)
    writer.add(make_episode(n_frames=N_FRAMES, episode_id="ep1", seed=1, kind="task", name="insert_tube",
                            cameras=("head",)))
    writer.add(make_episode(n_frames=N_FRAMES, episode_id="ep2", seed=2))
    return root


def test_task_tiles_show_the_head_camera_beside_the_pad_at_the_first_correction_in_touch(tmp_path):
    root = task_dataset(tmp_path / "ds")
    tiles, title, failed = _gallery_tiles(str(root), "right", 10)
    assert failed == [] and "first correction in touch" in title
    episodes = {e: Dataset.open(root).load_episode(e) for e in ("ep0", "ep1", "ep2")}
    (tile0, caption0), (tile1, caption1), (tile2, caption2) = tiles

    right = episodes["ep0"]["tactile/right/marked_rgb"]
    head = resize_to_height(episodes["ep0"]["scene/cameras/head/rgb"][3], right.shape[1])
    np.testing.assert_array_equal(tile0, np.concatenate([head, right[3]], axis=1))  # head, not wrist; frame 3
    assert caption0 == "lift_can, seed 0: grasp squareness (frame 3)"

    # no correction: the deepest press (the first of the equally deep frames), still beside the camera
    marked = episodes["ep1"]["tactile/right/marked_rgb"]
    head = resize_to_height(episodes["ep1"]["scene/cameras/head/rgb"][1], marked.shape[1])
    np.testing.assert_array_equal(tile1, np.concatenate([head, marked[1]], axis=1))
    assert caption1 == "insert_tube, seed 1"

    # an indenter episode: the pad alone, as before
    np.testing.assert_array_equal(tile2, episodes["ep2"]["tactile/right/marked_rgb"][1])
    assert caption2 == "sphere (gelsight_mini)"


def test_corrections_are_read_only_where_the_spec_puts_them():
    episode = make_episode(n_frames=N_FRAMES, kind="task", name="lift_can")
    assert recorded_corrections(episode.meta) == []
    for extra in ({"task": {}}, {"task": {"memory": {"corrections": "none"}}},
                  {"task": {"memory": {"corrections": [{"what": "x", "step": "soon"}]}}}):
        episode.meta.extra = extra
        assert recorded_corrections(episode.meta) == []
    episode.meta.extra = {"task": {"memory": {"corrections": [{"what": "x", "step": 99}, {"what": "y", "step": -2}]}}}
    assert recorded_corrections(episode.meta) == [(N_FRAMES - 1, "x"), (0, "y")]  # clamped to the frames


def test_the_gallery_command_writes_a_png_of_task_tiles(tmp_path):
    root = task_dataset(tmp_path / "ds")
    out = tmp_path / "gallery.png"
    done = subprocess.run([sys.executable, "-m", "univtac_data.cli.main", "preview", str(root), "--gallery",
                           "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == f"wrote {out}"
    from PIL import Image

    with Image.open(out) as image:
        width, height = image.size
    assert width > 2 * height  # three wide tiles in one row


def test_the_contact_sheet_spreads_its_frames_over_those_where_the_pad_touches(tmp_path):
    writer = DatasetWriter.open(tmp_path / "ds", storage="hdf5", sensors=["gelsight_mini"])
    writer.add(make_episode(n_frames=N_FRAMES, episode_id="ep0", kind="task", name="lift_can"))
    untouched = make_episode(n_frames=N_FRAMES, episode_id="ep1", seed=1, kind="task", name="lift_can")
    for name in ("depth_um", "contact_mask", "normal_force_n", "shear_force_n"):
        untouched.arrays[f"tactile/left/{name}"][:] = 0
    writer.add(untouched)

    frames, title = _dataset_frames(str(tmp_path / "ds"), "ep0", 2, "left")
    assert [f.title for f in frames] == ["frame 1", "frame 4"]  # frame 0 is before the touch
    assert title == "ep0 (gelsight_mini, pad left, 5 frames; shown: frames 1-4, where the pad touches)"
    frames, title = _dataset_frames(str(tmp_path / "ds"), "ep1", 2, "left")
    assert [f.title for f in frames] == ["frame 0", "frame 4"] and title == "ep1 (gelsight_mini, pad left, 5 frames)"
