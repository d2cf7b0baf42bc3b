"""The indenter generator: geometry, the closed-loop grasp, determinism, conformance, resume and Ray."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import h5py
import mujoco
import numpy as np
import pytest
from factories import stored_blosc_levels

from univtac_data import Dataset, check_episode, content_hash, get_sensor
from univtac_data.generators.allocator import keep_freed_memory
from univtac_data.generators.scene.gripper import MIN_OPENING_M, PADS
from univtac_data.generators.indenters.corpus import IndenterEpisodeSpec, corpus_specs, run_indenter_episode
from univtac_data.generators.indenters.scene import PAD_SIDE, indenter_geom_names, indenter_scene_xml
from univtac_data.generators.indenters.shapes import INDENTER_NAMES, INDENTERS, TIP_HEIGHT_M, indenter_mesh
from univtac_data.generators.scene.primitives import PRIMITIVE_NAMES, GraspParams, grasp, hold, squeeze_open_loop
from univtac_data.generators.runner import compression_level_for, run_corpus
from univtac_data.generators.scene.sim import GripperSim
from univtac_data.storage.backend import META_ATTR
from univtac_data.storage.errors import DatasetError


def cli(*args: str, **kwargs: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "univtac_data.cli.main", *args], capture_output=True, text=True,
                          timeout=600, **kwargs)  # type: ignore[call-overload]


def test_fourteen_indenters_span_convex_and_non_convex():
    assert len(INDENTER_NAMES) == 14 == len(set(INDENTER_NAMES))
    assert sum(i.convex for i in INDENTERS.values()) == 7
    for indenter in INDENTERS.values():
        lo, hi = indenter_mesh(indenter).bounds
        assert hi[2] == pytest.approx(TIP_HEIGHT_M, abs=2e-4), indenter.name
        assert max(hi[0] - lo[0], hi[1] - lo[1]) <= 0.0225, indenter.name  # inside the smallest imaged area


def make_sim(shape: str, sensor: str = "gelsight_mini") -> GripperSim:
    profile, indenter = get_sensor(sensor), INDENTERS[shape]
    model = mujoco.MjModel.from_xml_string(indenter_scene_xml(profile, indenter, gripper_pos=(0.0005, 0.001, 0.081)))
    sim = GripperSim(model, profile, {p: indenter_geom_names(indenter, PAD_SIDE[p]) for p in PADS}, "indenter",
                     PRIMITIVE_NAMES)
    sim.set_opening(0.024)
    for _ in range(50):
        sim.tick()
    sim.start_recording()
    return sim


@pytest.mark.parametrize("shape", ["sphere", "cross", "wave"])
def test_closed_loop_grasp_reaches_the_threshold_and_holds_it(shape):
    sim = make_sim(shape)
    threshold = 0.4
    outcome = grasp(sim, GraspParams(threshold_mm=threshold))
    assert outcome.reached
    hold(sim, 0.3)
    for pad, gap in sim.gap_mm().items():
        assert -gap == pytest.approx(threshold, abs=0.02), pad
    depth = max(int(sim.pixels[f"tactile/{p}/depth_um"].array().max()) for p in PADS) / 1000
    assert depth <= threshold + 0.1  # the approach overshoots by less than 0.1 mm
    assert depth < get_sensor("gelsight_mini").safe_indentation_mm


def test_open_loop_squeeze_drives_the_gel_past_its_limit():
    sim = make_sim("sphere")
    squeeze_open_loop(sim, MIN_OPENING_M, 0.3)
    assert max(-g for g in sim.gap_mm().values()) > get_sensor("gelsight_mini").safe_indentation_mm


def test_same_spec_same_episode_and_conforming():
    spec = IndenterEpisodeSpec("xense_ws", "star", 3, frames=12)
    a, b = run_indenter_episode(spec), run_indenter_episode(spec)
    assert content_hash(a) == content_hash(b)
    check_episode(a, get_sensor("xense_ws"))
    other = run_indenter_episode(IndenterEpisodeSpec("xense_ws", "star", 4, frames=12))
    assert content_hash(other) != content_hash(a)
    meta = a.meta
    assert meta.kind == "indenter" and meta.name == "star" and meta.n_frames == 12
    assert meta.safety.max_indentation_mm < get_sensor("xense_ws").safe_indentation_mm
    assert np.array_equal(a["timestamps_ns"], np.rint(np.arange(12) * 1e9 / 60).astype(np.int64))  # no drift
    assert a["tactile/left/contact_mask"][-1].any() and a["tactile/right/contact_mask"][-1].any()
    assert set(np.unique(a["scene/primitive"])) <= set(range(len(PRIMITIVE_NAMES)))


@pytest.mark.parametrize("shape", ["sphere", "dots", "torus"])
def test_geometric_episodes_do_not_depend_on_the_gap_field_above_the_gel(shape, monkeypatch):
    """The geometric contact's gap field is cut at the gel surface (the elastic one's 2 mm above it): an episode
    is the same, array for array, as one made with the higher cut (primitives, several spheres, a mesh)."""
    import univtac_data.generators.scene.sim as sim_module

    spec = IndenterEpisodeSpec("gf225", shape, 1, frames=14)
    at_gel = run_indenter_episode(spec)
    monkeypatch.setitem(sim_module.TACTILE_GAP_CUTOFF_MM, "geometric", 2.0)
    higher = run_indenter_episode(spec)
    assert at_gel["tactile/left/contact_mask"].any() and at_gel["tactile/right/contact_mask"].any()
    assert content_hash(at_gel) == content_hash(higher)


def test_episode_specs_have_stable_ids_and_seeds():
    specs = corpus_specs(["gf225"], ["sphere", "torus"], 2, base_seed=7)
    assert [s.episode_id for s in specs] == ["gf225-sphere-0000", "gf225-sphere-0001", "gf225-torus-0000",
                                             "gf225-torus-0001"]
    assert specs[0].seed == IndenterEpisodeSpec("gf225", "sphere", 0, base_seed=7).seed
    assert len({s.seed for s in specs}) == 4


ARGS = ["generate", "indenters", "--shapes", "sphere,cross,dots", "--episodes-per-shape", "2",
        "--frames-per-episode", "10"]


def test_generate_is_resumable_after_a_kill_and_ends_identical(tmp_path):
    reference = cli(*ARGS, "--out", str(tmp_path / "ref"), "--workers", "1")
    assert reference.returncode == 0, reference.stderr
    assert "6 episodes, 60 frames" in reference.stdout

    with open(tmp_path / "log", "w") as log:
        proc = subprocess.Popen([sys.executable, "-m", "univtac_data.cli.main", *ARGS, "--out", str(tmp_path / "cut"),
                                 "--workers", "1"], stdout=log, stderr=log)
    index = tmp_path / "cut/meta/episodes.parquet"
    deadline = time.monotonic() + 300
    # killed at the first committed episode: five more leave a loaded machine time to see it before the run ends
    while proc.poll() is None and time.monotonic() < deadline:
        if index.exists() and len(Dataset.open(tmp_path / "cut")) >= 1:
            os.kill(proc.pid, signal.SIGKILL)
            break
        time.sleep(0.02)
    proc.wait(timeout=60)
    assert proc.returncode == -signal.SIGKILL, (tmp_path / "log").read_text()
    assert 1 <= len(Dataset.open(tmp_path / "cut")) < 6

    resumed = cli(*ARGS, "--out", str(tmp_path / "cut"), "--workers", "2")
    assert resumed.returncode == 0, resumed.stderr
    assert "already there" in resumed.stdout
    ref, cut = Dataset.open(tmp_path / "ref"), Dataset.open(tmp_path / "cut")
    assert {k: v.sha256 for k, v in ref.index.items()} == {k: v.sha256 for k, v in cut.index.items()}
    assert (tmp_path / "ref/meta/episodes.parquet").read_bytes() == index.read_bytes()
    assert cut.verify_checksums() == []


def test_ray_executor_makes_the_same_episodes(tmp_path):
    pytest.importorskip("ray")
    specs = corpus_specs(["gelsight_mini"], ["hexagon"], 2, frames=6)
    local = run_corpus(str(tmp_path / "local"), specs, workers=1, progress=False)
    on_ray = run_corpus(str(tmp_path / "ray"), specs, workers=2, executor="ray", progress=False)
    assert local.written == on_ray.written == 2 and not on_ray.failed
    a, b = Dataset.open(tmp_path / "local"), Dataset.open(tmp_path / "ray")
    assert {k: v.sha256 for k, v in a.index.items()} == {k: v.sha256 for k, v in b.index.items()}


def test_bad_options_and_mismatched_resume_are_refused(tmp_path):
    bad = cli("generate", "indenters", "--out", str(tmp_path / "x"), "--shapes", "sphere,banana")
    assert bad.returncode == 2 and "unknown indenter banana" in bad.stderr and "Traceback" not in bad.stderr
    first = cli("generate", "indenters", "--out", str(tmp_path / "d"), "--shapes", "cone", "--episodes-per-shape",
                "1", "--frames-per-episode", "5", "--workers", "1")
    assert first.returncode == 0, first.stderr
    (written,) = (tmp_path / "d" / "episodes").glob("*.h5")
    assert stored_blosc_levels(written) == {1}  # geometric episodes: the fastest level
    again = cli("generate", "indenters", "--out", str(tmp_path / "d"), "--shapes", "cone", "--episodes-per-shape",
                "1", "--frames-per-episode", "7", "--workers", "1")
    assert again.returncode == 2 and "frames=5" in again.stderr and "frames=7" in again.stderr
    for level in ("0", "10"):
        refused = cli("generate", "indenters", "--out", str(tmp_path / "z"), "--compression-level", level)
        assert refused.returncode == 2 and f"--compression-level must be 1 to 9 (got {level})" in refused.stderr
        assert "Traceback" not in refused.stderr and not (tmp_path / "z").exists()
    chosen = cli("generate", "indenters", "--out", str(tmp_path / "c"), "--shapes", "cone", "--episodes-per-shape",
                 "1", "--frames-per-episode", "3", "--workers", "1", "--compression-level", "6")
    assert chosen.returncode == 0, chosen.stderr
    (written,) = (tmp_path / "c" / "episodes").glob("*.h5")
    assert stored_blosc_levels(written) == {6}


def test_the_automatic_compression_level_follows_sensor_and_contact_model():
    """Level 1 for geometric contact, 3 for elastic, 2 for the GF225's geometric frames (which level 1 leaves
    over the size budget); a chosen level always wins."""
    def level(sensor: str, method: str, chosen: int | None = None) -> int:
        return compression_level_for(IndenterEpisodeSpec(sensor, "sphere", 0, contact_method=method), chosen)

    assert [level(s, "geometric") for s in ("gelsight_mini", "xense_ws", "gf225")] == [1, 1, 2]
    assert [level(s, "elastic") for s in ("gelsight_mini", "xense_ws", "gf225")] == [3, 3, 3]
    assert level("gf225", "geometric", 6) == level("gelsight_mini", "elastic", 1) + 5 == 6


def test_generated_episodes_pass_every_validator_rule(tmp_path):
    from univtac_data.validators import validate

    # the broad dome slides most under a twist; the cross and the dots make several contact patches
    specs = corpus_specs(["gelsight_mini"], ["curved_surface", "cross", "dots"], 2, frames=60, base_seed=11)
    summary = run_corpus(str(tmp_path / "ds"), specs, workers=1, progress=False)
    assert summary.written == 6 and not summary.failed
    report = validate(tmp_path / "ds")
    assert report.ok, report.failed_episodes()
    ds = Dataset.open(tmp_path / "ds")
    assert max(row.max_slip_mm for row in ds.index.values()) < 1.0


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc allocator tuning")
def test_workers_keep_freed_memory_on_linux():
    assert keep_freed_memory() is True
    assert keep_freed_memory() is True  # once per process, then cached


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc allocator tuning")
def test_mmap_threshold_can_be_fixed_in_a_fresh_process():
    """The training reader's setting, in its own process so the test process's allocator stays as it was."""
    code = ("from univtac_data.generators.allocator import fix_mmap_threshold; "
            "import sys; sys.exit(0 if fix_mmap_threshold(128 * 1024) else 3)")
    assert subprocess.run([sys.executable, "-c", code], timeout=60).returncode == 0


def test_gel_layer_option_is_recorded_checked_on_resume_and_elastic_only(tmp_path):
    geometric = cli("generate", "indenters", "--out", str(tmp_path / "g"), "--gel", "layer")
    assert geometric.returncode == 2 and "--gel layer applies to --contact elastic" in geometric.stderr
    assert not (tmp_path / "g").exists()
    args = ["generate", "indenters", "--out", str(tmp_path / "d"), "--shapes", "sphere", "--episodes-per-shape", "1",
            "--frames-per-episode", "20", "--workers", "1", "--contact", "elastic"]
    first = cli(*args, "--gel", "layer")
    assert first.returncode == 0, first.stderr
    episode = Dataset.open(tmp_path / "d").load_episode("gelsight_mini-sphere-0000")
    assert episode.meta.generator.settings["gel"] == "layer"
    (written,) = (tmp_path / "d" / "episodes").glob("*.h5")
    assert stored_blosc_levels(written) == {3}  # elastic episodes: the simulation sets the pace, not level 3
    assert episode.meta.safety.max_indentation_mm > 0.1   # pressed, not just approached
    validated = cli("validate", str(tmp_path / "d"))   # every rule holds for layer episodes too
    assert validated.returncode == 0, validated.stdout + validated.stderr
    other = cli(*args)  # the default half-space into a layer dataset: refused, nothing written
    assert other.returncode == 2 and "gel='layer'" in other.stderr and "gel='half_space'" in other.stderr


def test_resume_takes_a_setting_missing_from_older_episodes_as_its_default(tmp_path):
    """Episodes written before a setting existed (``gel``, 0.2.0) were made with its default."""
    spec = IndenterEpisodeSpec("gelsight_mini", "cone", 0, frames=3)
    assert run_corpus(str(tmp_path / "d"), [spec], workers=1, progress=False).written == 1
    with h5py.File(next((tmp_path / "d" / "episodes").glob("*.h5")), "r+") as f:
        meta = json.loads(f.attrs[META_ATTR])
        del meta["generator"]["settings"]["gel"]
        f.attrs[META_ATTR] = json.dumps(meta)
    summary = run_corpus(str(tmp_path / "d"), [spec, IndenterEpisodeSpec("gelsight_mini", "cone", 1, frames=3)],
                         workers=1, progress=False)
    assert summary.written == 1 and not summary.failed
    with pytest.raises(DatasetError, match="gel='half_space'.*gel='layer'"):
        run_corpus(str(tmp_path / "d"), [IndenterEpisodeSpec("gelsight_mini", "cone", 0, frames=3, gel="layer")],
                   workers=1, progress=False)
