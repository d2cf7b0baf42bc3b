"""The encoder pretraining recipe (examples/pretrain_encoder.py): the held-out split, training on a tiny
generated corpus, checkpoints, and the symmetry-aware pose target."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
import torch
from torch.nn import functional as F

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
SHAPES = ("cross", "pacman", "sphere")


def load(name: str) -> ModuleType:
    sys.path.insert(0, str(EXAMPLES))
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module", autouse=True)
def one_thread():  # type: ignore[no-untyped-def]
    """One torch thread: the tensors here are tiny, and a second thread only waits on a shared machine."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def recipe() -> ModuleType:
    return load("pretrain_encoder")


@pytest.fixture(scope="module")
def corpus_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three shapes x three episodes x 14 frames of GelSight Mini."""
    from univtac_data.generators.indenters.corpus import IndenterEpisodeSpec, run_indenter_episode
    from univtac_data.storage import DatasetWriter

    root = tmp_path_factory.mktemp("recipe") / "corpus"
    writer = DatasetWriter.open(root, storage="hdf5", sensors=["gelsight_mini"])
    for shape in SHAPES:
        for k in range(3):
            writer.add(run_indenter_episode(IndenterEpisodeSpec("gelsight_mini", shape, k, frames=14)))
    writer.close()
    return root


@pytest.fixture(scope="module")
def corpus(recipe: ModuleType, corpus_root: Path):  # type: ignore[no-untyped-def]
    """The corpus read at 24 x 32."""
    return recipe.load_corpus(corpus_root, "gelsight_mini", (24, 32), 0.01, cache=corpus_root.parent / "cache.pt")


def test_probe_never_sees_frames_of_its_test_episodes(  # type: ignore[no-untyped-def]
        recipe: ModuleType, corpus) -> None:
    train, held, train_ids, held_ids = recipe.split_masks(corpus, 0.34)
    assert not set(train_ids) & set(held_ids)
    assert not (train & held).any() and (train | held).all()
    train_eps = {corpus.episode_ids[e] for e in corpus.episode[train].tolist()}
    held_eps = {corpus.episode_ids[e] for e in corpus.episode[held].tolist()}
    assert train_eps == set(train_ids) and held_eps == set(held_ids) and not train_eps & held_eps
    # every shape is on both sides, so the probe is asked only about shapes it was fitted on
    assert set(corpus.label[train].tolist()) == set(corpus.label[held].tolist()) == set(range(len(SHAPES)))
    # the probe is fitted on the training rows only: a held-out row's prediction depends on no other
    # held-out row (standardisation statistics and weights come from the training rows)
    gen = torch.Generator().manual_seed(0)
    feats = torch.randn(len(corpus.label), 16, generator=gen)
    pred = recipe.linear_probe(feats[train], corpus.label[train], feats[held], len(SHAPES))
    other = feats[held].clone()
    other[1:] = 100.0 * torch.randn(other[1:].shape, generator=gen)
    assert recipe.linear_probe(feats[train], corpus.label[train], other, len(SHAPES))[0] == pred[0]
    # the split is by episode id alone: another episode never moves an existing one of another shape
    ids = train_ids + held_ids
    _, more_held = recipe.held_out_split(ids + ["gelsight_mini-cross-0099"],
                                         [i.split("-")[1] for i in ids] + ["cross"], 0.34)
    assert {i for i in more_held if "-cross-" not in i} == {i for i in held_ids if "-cross-" not in i}
    # another split seed holds out other episodes, with the same guarantees
    _, other_held_mask, other_train, other_held = recipe.split_masks(corpus, 0.34, split_seed=1)
    assert not set(other_train) & set(other_held) and len(other_held) == len(held_ids)
    assert set(other_held) != set(held_ids)
    assert set(corpus.label[other_held_mask].tolist()) == set(range(len(SHAPES)))


def test_corpus_keeps_frames_in_contact_with_pose_targets(corpus) -> None:  # type: ignore[no-untyped-def]
    assert corpus.marked.shape[1:] == (3, 24, 32) and corpus.marked.dtype == torch.uint8
    assert float(corpus.peak.min()) >= 0.01
    # the indenter's mounting face is 5 mm (tip height) behind the gel, along the pad normal (z)
    assert torch.allclose(corpus.position[:, 2].abs().mean(), torch.tensor(5.0), atol=0.6)
    assert float(corpus.position[:, :2].abs().max()) < 3.0
    orders = {corpus.shapes[int(lab)]: int(o) for lab, o in zip(corpus.label, corpus.order)}
    assert orders == {"cross": 4, "pacman": 1, "sphere": 0}


def test_symmetry_from_the_indenter_definitions() -> None:
    enc = load("tactile_encoder")
    assert [enc.rotational_symmetry(s) for s in ("sphere", "hexagon", "star", "pacman", "cylinder_side")] == \
        [enc.CONTINUOUS, 6, 5, 1, 2]
    # a yaw error is measured modulo the symmetry: a cross turned by 88 deg is 2 deg off; round shapes have none
    yaw = torch.tensor([0.0, 0.0, 0.0])
    order = torch.tensor([4, 1, 0])
    turn = math.radians(88.0)
    pred = torch.tensor([[math.cos(4 * turn), math.sin(4 * turn)], [math.cos(turn), math.sin(turn)], [1.0, 0.0]])
    err = enc.yaw_error_deg(pred, yaw, order)
    assert err[0].item() == pytest.approx(2.0, abs=1e-3) and err[1].item() == pytest.approx(88.0, abs=1e-3)
    assert math.isnan(err[2].item())
    target, observable = enc.yaw_target(torch.tensor([0.1, 0.1 + math.pi / 2]), torch.tensor([4, 4]))
    assert torch.allclose(target[0], target[1], atol=1e-5) and observable.all()


def test_training_lowers_the_loss_and_checkpoints_reload(  # type: ignore[no-untyped-def]
        recipe: ModuleType, corpus, tmp_path: Path) -> None:
    train, held, _, _ = recipe.split_masks(corpus, 0.34)
    model = recipe.make_model(corpus, train, (24, 32), seed=0)
    history = recipe.train(model, corpus, train, steps=40, batch_size=16, lr=3e-3, seed=0, log_every=1000)
    first = np.mean([h["total"] for h in history[:5]])
    last = np.mean([h["total"] for h in history[-5:]])
    assert np.isfinite(last) and last < 0.8 * first, (first, last)
    path = tmp_path / "encoder.pt"
    recipe.save_checkpoint(model, path, corpus.shapes)
    again = recipe.load_checkpoint(path)
    model.eval()
    images = corpus.marked[:8].float() / 255.0
    with torch.no_grad():
        a, b = model(images), again(images)
    for key in a:
        assert torch.equal(a[key], b[key]), key
    feats, _ = recipe.encode_all(again, corpus)
    report = recipe.probe_report(feats, corpus, train, held, seed=0)
    assert report["samples"] == int(held.sum()) and 0.0 <= report["accuracy"] <= 1.0
    lo, hi = report["wilson95"]
    assert lo <= report["accuracy"] <= hi


def test_turned_consistency_view_keeps_the_imprint() -> None:
    """The consistency view's turn is a rigid turn in pixel space (a non-square image must not shear it)."""
    enc = load("tactile_encoder")
    image = torch.zeros(1, 1, 48, 64)
    image[0, 0, 24, 32:44] = 1.0  # a 12-pixel line from the centre toward +x
    turned = enc.rotate_images(image, torch.tensor([math.pi / 2]))
    ys, xs = torch.nonzero(turned[0, 0] > 0.3, as_tuple=True)
    assert int(xs.max() - xs.min()) <= 1 and 10 <= int(ys.max() - ys.min()) <= 12  # now along +y, same length
    assert int(ys.min()) >= 23  # +x turned toward +y (down, as displayed)
    assert torch.allclose(enc.rotate_images(image, torch.tensor([0.0])), image, atol=1e-5)
    gen = torch.Generator().manual_seed(0)
    assert torch.equal(enc.Augment().rotate(image, gen), image)  # off unless asked for
    many = image.expand(64, 1, 48, 64)
    turned = enc.Augment(rotate_deg=180.0).rotate(many, gen)
    # any turn: the line's tip lands in every quadrant around the centre
    tips = [torch.nonzero(t[0] > 0.3).float().mean(0) - torch.tensor([23.5, 31.5]) for t in turned]
    assert {(bool(t[0] > 0), bool(t[1] > 0)) for t in tips} == {(a, b) for a in (False, True) for b in (False, True)}


def test_episode_consistency_pulls_one_episode_together_and_pushes_others_apart() -> None:
    enc = load("tactile_encoder")
    episode = torch.tensor([0, 0, 1, 1, 2, 2])
    basis = torch.eye(3)
    together = basis[episode]  # frames of one episode share a direction, episodes are orthogonal
    mixed = basis[torch.tensor([0, 1, 1, 2, 2, 0])]  # every frame's neighbour is another episode's
    low = enc.episode_consistency(together, episode, temperature=0.2)
    high = enc.episode_consistency(mixed, episode, temperature=0.2)
    assert float(low) < 0.05 and float(high) > 3.0  # 5 = 1 / temperature: the positive is never nearest
    # a frame without a partner of its episode in the batch is no anchor, but is still a negative for others
    lone = torch.tensor([0, 0, 1, 1, 2, 3])
    emb = torch.cat([together[:4], basis[:1], basis[2:3]])  # the lone frame of episode 2 sits on episode 0
    assert float(enc.episode_consistency(emb, lone, 0.2)) > float(enc.episode_consistency(together, episode, 0.2))


def test_average_and_maximum_pooled_features(  # type: ignore[no-untyped-def]
        recipe: ModuleType, corpus, tmp_path: Path) -> None:
    enc = load("tactile_encoder")
    train, _, _, _ = recipe.split_masks(corpus, 0.34)
    model = recipe.make_model(corpus, train, (24, 32), seed=0, pool="avgmax").eval()
    images = corpus.marked[:4].float() / 255.0
    with torch.no_grad():
        feats = model.encode(images)
        fmap = model.backbone((images - model.mean) / model.std)
    assert model.config.feature_dim == feats.shape[1] == 2 * model.config.widths[-1]
    assert torch.allclose(feats[:, :128], fmap.mean((2, 3)), atol=1e-5)
    assert torch.allclose(feats[:, 128:], fmap.amax((2, 3)))
    path = tmp_path / "encoder.pt"
    recipe.save_checkpoint(model, path, corpus.shapes)
    with torch.no_grad():
        assert torch.equal(recipe.load_checkpoint(path).encode(images), feats)
    # checkpoints written before the option existed have no "pool" and load as average-pooled
    old = {k: v for k, v in model.config.to_dict().items() if k != "pool"}
    assert enc.EncoderConfig(**{**old, "widths": tuple(old["widths"])}).pool == "avg"
    with pytest.raises(ValueError):
        enc.EncoderConfig(pool="median")


def test_fewer_training_episodes_keep_the_same_held_out_episodes(  # type: ignore[no-untyped-def]
        recipe: ModuleType, corpus) -> None:
    train, held, train_ids, held_ids = recipe.split_masks(corpus, 0.34)
    few_train, few_held, few_train_ids, few_held_ids = recipe.split_masks(corpus, 0.34, max_train=1)
    assert few_held_ids == held_ids and torch.equal(few_held, held)
    assert set(few_train_ids) < set(train_ids) and not set(few_train_ids) & set(held_ids)
    per_shape = [i.split("-")[1] for i in few_train_ids]
    assert sorted(per_shape) == sorted(SHAPES)  # one training episode of each shape
    # the samples of the episodes left out are in neither mask, and the training mask holds exactly its episodes
    assert not (few_train & few_held).any() and int((few_train | few_held).sum()) < len(corpus.label)
    assert {corpus.episode_ids[e] for e in corpus.episode[few_train].tolist()} == set(few_train_ids)


def test_larger_input_with_small_reconstruction_targets(  # type: ignore[no-untyped-def]
        recipe: ModuleType, corpus, corpus_root: Path, tmp_path: Path) -> None:
    """A 48 x 64 input fed as 2 x 2 pixel blocks (space to depth) with 24 x 32 targets: the corpus holds each
    at its size, the decoder rebuilds the targets' size, training runs, and the checkpoint reloads."""
    enc = load("tactile_encoder")
    big = recipe.load_corpus(corpus_root, "gelsight_mini", (48, 64), 0.01, target_size=(24, 32))
    assert big.marked.shape[1:] == (3, 48, 64) and big.pure.shape[1:] == (3, 24, 32)
    assert big.depth.shape[1:] == (1, 24, 32) and torch.equal(big.label, corpus.label)
    assert torch.equal(big.pure, corpus.pure) and torch.equal(big.depth, corpus.depth)  # same targets
    # the larger marked image, averaged over 2 x 2 blocks, is the small one (area resizing)
    assert float((F.avg_pool2d(big.marked.float(), 2) - corpus.marked.float()).abs().max()) <= 1.0
    train, _, _, _ = recipe.split_masks(big, 0.34)
    model = recipe.make_model(big, train, (48, 64), seed=0, space_to_depth=2)
    assert model.config.target_hw == (24, 32) and model.backbone[0][0].in_channels == 12
    history = recipe.train(model, big, train, steps=3, batch_size=8, lr=1e-3, seed=0, log_every=1000)
    assert all(np.isfinite(h["total"]) for h in history)
    model.eval()
    with torch.no_grad():
        out = model(big.marked[:4].float() / 255.0)
    assert out["pure_rgb"].shape == (4, 3, 24, 32) and out["features"].shape == (4, model.config.feature_dim)
    # the first stage sees every pixel: changing one pixel inside a 2 x 2 block changes the features
    image = big.marked[:1].float() / 255.0
    nudged = image.clone()
    nudged[0, :, 21, 33] += 0.5
    with torch.no_grad():
        assert not torch.allclose(model.encode(image), model.encode(nudged))
    path = tmp_path / "encoder.pt"
    recipe.save_checkpoint(model, path, big.shapes)
    with torch.no_grad():
        assert torch.equal(recipe.load_checkpoint(path)(big.marked[:4].float() / 255.0)["pure_rgb"], out["pure_rgb"])
    for bad in ({"space_to_depth": 0}, {"height": 47, "space_to_depth": 2}, {"target_height": 24}):
        with pytest.raises(ValueError):
            enc.EncoderConfig(**bad)


def test_a_policy_feeds_the_frozen_encoder_images_of_its_input_size() -> None:
    """A policy's tactile images are resized to ``tactile_hw``: an encoder trained on another size must be
    refused, not fed images whose imprint is at another scale."""
    load("tactile_encoder")
    act = load("act_policy")
    enc = load("tactile_encoder").EncoderConfig(height=96, width=128, space_to_depth=2, target_height=48,
                                                target_width=64).to_dict()
    with pytest.raises(ValueError, match="tactile_hw"):
        act.PolicyConfig(variant="vision_encoder", encoder=enc)
    assert act.PolicyConfig(variant="vision_encoder", encoder=enc, tactile_hw=(96, 128)).tactile_hw == (96, 128)
    assert act.PolicyConfig(variant="vision_encoder", encoder=load("tactile_encoder").EncoderConfig().to_dict())


@pytest.mark.parametrize("args, message", [
    (["--space-to-depth", "5"], "--space-to-depth 5: must be a positive divisor"),
    (["--target-size", "0", "64"], "--image-size and --target-size must be positive"),
    (["--train-episodes", "0"], "--train-episodes must be at least 1"),
])
def test_recipe_refuses_bad_options_in_one_line(args: list[str], message: str,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    recipe = load("pretrain_encoder")
    with pytest.raises(SystemExit) as stop:
        recipe.parse_args(["--data", "corpus", *args])
    assert stop.value.code == 2 and message in capsys.readouterr().err


def test_recipe_names_a_missing_corpus_in_one_line(tmp_path: Path) -> None:
    recipe = load("pretrain_encoder")
    with pytest.raises(SystemExit) as stop:
        recipe.main(["--data", str(tmp_path / "missing"), "--out-dir", str(tmp_path / "out"), "--threads", "1"])
    assert str(stop.value) == f"pretrain_encoder: {tmp_path / 'missing'}: no such file or directory"


def test_a_corpus_regenerated_into_the_cached_directory_is_read_again(  # type: ignore[no-untyped-def]
        recipe: ModuleType, corpus_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The corpus cache records the episodes' digests: other episodes at the same path are read, not the
    cached frames; a cut-short cache is read again too, and the cache is replaced whole."""
    import shutil

    from univtac_data import DatasetWriter
    from univtac_data.generators.indenters.corpus import IndenterEpisodeSpec, run_indenter_episode

    data, cache = tmp_path / "corpus", tmp_path / "cache.pt"
    shutil.copytree(corpus_root, data)
    first = recipe.load_corpus(data, "gelsight_mini", (24, 32), 0.01, cache=cache)
    assert len(first.episode_ids) == 3 * len(SHAPES) and cache.exists()
    assert not list(tmp_path.glob("*.part"))

    shutil.rmtree(data)  # regenerated: one episode of another seed
    with DatasetWriter.open(data, storage="hdf5", sensors=["gelsight_mini"]) as writer:
        writer.add(run_indenter_episode(IndenterEpisodeSpec("gelsight_mini", "sphere", 7, frames=14)))
    again = recipe.load_corpus(data, "gelsight_mini", (24, 32), 0.01, cache=cache)
    assert again.episode_ids == ["gelsight_mini-sphere-0007"] and again.shapes == ["sphere"]

    cache.write_bytes(cache.read_bytes()[:100])
    reread = recipe.load_corpus(data, "gelsight_mini", (24, 32), 0.01, cache=cache)
    assert "is unreadable" in capsys.readouterr().out
    assert reread.episode_ids == again.episode_ids and torch.equal(reread.marked, again.marked)
