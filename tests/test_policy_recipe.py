"""The policy-baseline recipe (examples/act_policy.py, examples/train_policy.py): demonstrations subsampled to
the policy's rate, is_pad masking, temporal ensembling, training on a tiny corpus, checkpoints that reload
to identical outputs, the frozen encoder staying frozen, and a trained policy evaluated end to end through
``univtac-data evaluate --policy act_policy:from_env --rate-hz``."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from univtac_data import DatasetWriter
from univtac_data.envs.evaluate import step_limit
from univtac_data.envs.task_env import TaskEnv
from univtac_data.generators.tasks.base import TaskConfig
from univtac_data.generators.tasks.collect import TaskEpisodeSpec, run_expert

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
if str(EXAMPLES) not in sys.path:
    sys.path.insert(0, str(EXAMPLES))

from act_policy import (CHECKPOINT_ENV, STD_FLOOR, ChunkPolicy, Normalization, PolicyConfig, TemporalEnsembler,  # noqa: E402
                        absolute_chunk, chunk_targets, load_checkpoint, masked_l1, quat_mul, save_checkpoint,
                        touch_signals)
from train_policy import main as train_policy_main  # noqa: E402
from train_policy import (chart, difference_interval, history_rows, load_demos, make_batch,  # noqa: E402
                          merged_evaluation, pooled_rows, touch_effects, train)

os.environ.setdefault("MUJOCO_GL", "egl")
TASK = "pull_out_key"


def tiny_config(variant: str = "vision_tactile", **kw) -> PolicyConfig:
    return PolicyConfig(variant=variant, cameras=(), chunk=4, rate_hz=10.0, d_model=32, heads=2, encoder_layers=1,
                        decoder_layers=1, feedforward=64, dropout=0.0, **kw)


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    """One Pull-out Key demonstration at 50 Hz, without cameras."""
    root = tmp_path_factory.mktemp("policy") / "ds"
    outcome = run_expert(TaskEpisodeSpec(TASK, 0, TaskConfig(cameras=False)))
    assert outcome.episode is not None
    DatasetWriter.open(root).add(outcome.episode)
    return root, outcome.episode


@pytest.fixture(scope="module")
def demos(corpus):
    root, _ = corpus
    return load_demos(root, TASK, tiny_config(), stride=3, log=lambda _: None)


@pytest.fixture(scope="module")
def trained(demos):
    torch.set_num_threads(1)
    net, norm, losses = train(demos, tiny_config(), steps=60, batch_size=16, lr=2e-3, seed=0, shift_px=0,
                              log=lambda _: None)
    return net, norm, losses


def test_demonstrations_are_subsampled_to_the_policy_rate(corpus, demos):
    _, episode = corpus
    actions = episode["robot/action"]
    n = len(actions)
    assert demos.demo_rate_hz == 50.0 and demos.subsample == 5
    t = demos.tensors
    steps = np.arange(0, n, 3)
    assert len(demos) == len(steps)
    for k in (0, 7, len(steps) - 1):
        s = steps[k]
        # the target 1 / 10 s ahead is the action recorded 5 frames on: a[s + 4], a[s + 9], ...
        want = [actions[min(s + 4 + 5 * j, n - 1)] for j in range(4)]
        assert np.allclose(t["action"][k].numpy(), np.array(want, np.float32))
        assert t["action_is_pad"][k].tolist() == [s + 4 + 5 * j >= n for j in range(4)]
        pose = np.concatenate([episode["robot/ee_pose"][s], [episode["robot/gripper_width_m"][s]]])
        assert np.allclose(t["agent_pos"][k].numpy(), pose, atol=1e-6)
    assert t["action_is_pad"][-1].any() and not t["action_is_pad"][0].any()
    assert t["tactile_left"].shape[1:] == (3, 48, 64) and t["tactile_left"].dtype == torch.uint8


def test_is_pad_rows_never_count_in_the_loss():
    gen = torch.Generator().manual_seed(0)
    pred, target = torch.randn(3, 5, 8, generator=gen), torch.randn(3, 5, 8, generator=gen)
    is_pad = torch.zeros(3, 5, dtype=torch.bool)
    is_pad[0, 3:] = True
    is_pad[2, 1:] = True
    loss = masked_l1(pred, target, is_pad)
    by_hand = (pred - target).abs()[~is_pad].mean()
    assert torch.isclose(loss, by_hand)
    changed = target.clone()
    changed[is_pad] += 100.0  # whatever the padding holds
    assert torch.equal(masked_l1(pred, changed, is_pad), loss)
    changed[0, 0, 0] += 1.0   # a real action does count
    assert not torch.isclose(masked_l1(pred, changed, is_pad), loss)
    assert not torch.isclose(masked_l1(pred, target, torch.zeros_like(is_pad)), loss)


def test_normalisation_keeps_millimetre_components_and_floors_still_quaternion_components():
    """Pull-out Key's opening moves 1.5 mm (std) and its x, y 3 mm: normalised by those, not by a 10 mm floor
    that would make a 0.5 mm opening error look like 0.05; a quaternion component that never moves is
    floored (a tiny deviation at rollout must not become a huge input)."""
    gen = torch.Generator().manual_seed(0)
    n, chunk = 400, 5
    spread = torch.tensor([3e-3, 3e-3, 9e-3, 0.2, 0.0, 0.0, 0.3, 1.5e-3])
    mean = torch.tensor([0.0, 0.0, 0.1, 0.0, 1.0, 0.0, 0.0, 7e-3])
    agent = mean + spread * torch.randn(n, 8, generator=gen)
    actions = mean + spread * torch.randn(n, chunk, 8, generator=gen)
    is_pad = torch.zeros(n, chunk, dtype=torch.bool)
    is_pad[:, -1] = True
    actions[is_pad] = 5.0  # padding never counts in the statistics
    norm = Normalization.fit(agent, actions, is_pad)
    for std in (norm.agent_std, norm.action_std):
        for k in (0, 1, 2, 3, 6, 7):
            assert abs(std[k].item() / spread[k].item() - 1) < 0.15, (k, std[k].item())
        assert math.isclose(std[4].item(), STD_FLOOR[4], rel_tol=1e-6) and math.isclose(std[5].item(), STD_FLOOR[5], rel_tol=1e-6)
    assert abs(norm.action_mean[7].item() - 7e-3) < 3e-4
    # a 0.5 mm opening error is a third of a normalised unit, as the loss sees it
    assert 0.25 < 5e-4 / norm.action_std[7].item() < 0.45
    tiny = Normalization.fit(torch.full((10, 8), 0.01), torch.full((10, 2, 8), 0.01), torch.zeros(10, 2, dtype=torch.bool))
    assert torch.equal(tiny.action_std, torch.tensor(STD_FLOOR, dtype=torch.float32))


def test_temporal_ensembling_weights_every_prediction_for_the_step():
    k, chunk = 0.5, 3
    ens = TemporalEnsembler(chunk, k)
    chunks = [np.full((chunk, 2), 10.0 * (j + 1)) + np.arange(chunk)[:, None] for j in range(5)]
    assert np.allclose(ens(chunks[0]), chunks[0][0])
    out = ens(chunks[1])  # step 1: chunk 0's row 1 (older, weight 1) and chunk 1's row 0 (weight e^-k)
    assert np.allclose(out, (chunks[0][1] + math.exp(-k) * chunks[1][0]) / (1 + math.exp(-k)))
    out = ens(chunks[2])
    w = np.exp(-k * np.arange(3))
    want = (w[0] * chunks[0][2] + w[1] * chunks[1][1] + w[2] * chunks[2][0]) / w.sum()
    assert np.allclose(out, want)
    out = ens(chunks[3])  # chunk 0 covers steps 0-2 only: it drops out
    want = (w[0] * chunks[1][2] + w[1] * chunks[2][1] + w[2] * chunks[3][0]) / w.sum()
    assert np.allclose(out, want)
    ens.reset()
    assert np.allclose(ens(chunks[4]), chunks[4][0])
    newest = TemporalEnsembler(chunk, -50.0)  # a negative k weights the newest prediction most
    newest(chunks[0])
    assert np.allclose(newest(chunks[1]), chunks[1][0])


def test_training_on_a_tiny_corpus_lowers_the_loss(trained):
    _, _, losses = trained
    assert len(losses) == 60 and all(math.isfinite(x) for x in losses)
    assert np.mean(losses[-10:]) < 0.7 * np.mean(losses[:10])


def test_a_checkpoint_reloads_to_identical_outputs(trained, demos, tmp_path):
    net, norm, _ = trained
    save_checkpoint(tmp_path / "policy.pt", net, norm)
    again, norm2, _ = load_checkpoint(tmp_path / "policy.pt")
    assert again.config == net.config
    env = TaskEnv(TASK, cameras=False, rate_hz=10.0)
    obs, _ = env.reset(seed=1_000_000)
    env.close()
    a, b = ChunkPolicy(net, norm), ChunkPolicy(again, norm2)
    assert np.array_equal(a.predict_chunk(obs), b.predict_chunk(obs))
    assert a.predict_chunk(obs).shape == (4, 8)
    action = a.act(obs)
    assert action.shape == (8,) and abs(np.linalg.norm(action[3:7]) - 1) < 1e-5


def test_the_pretrained_encoder_stays_frozen(demos, tmp_path):
    from pretrain_encoder import save_checkpoint as save_encoder
    from tactile_encoder import EncoderConfig, TactileEncoder

    torch.manual_seed(1)
    encoder = TactileEncoder(EncoderConfig(pool="avgmax"))  # the recipe's default: 256 features a pad
    save_encoder(encoder, tmp_path / "encoder.pt", [])
    config = tiny_config("vision_encoder", encoder=encoder.config.to_dict())
    cache = type(demos)(dict(demos.tensors), demos.episodes, demos.demo_rate_hz, demos.subsample)
    net, norm, losses = train(cache, config, steps=5, batch_size=8, lr=1e-3, seed=0, shift_px=0,
                              encoder_path=str(tmp_path / "encoder.pt"), log=lambda _: None)
    for name, value in encoder.state_dict().items():  # weights and BatchNorm statistics alike
        assert torch.equal(net.encoder.state_dict()[name], value), name
    # features precomputed for training equal the ones the rollout computes from the images
    images = demos.tensors["tactile_left"][:4].float() / 255.0
    assert torch.allclose(cache.tensors["feat_left"][:4], encoder.eval().encode(images), atol=1e-5)
    obs = {"agent_pos": torch.zeros(4, 8), "tactile_left": images,
           "tactile_right": demos.tensors["tactile_right"][:4].float() / 255.0}
    feats = {"agent_pos": obs["agent_pos"], "feat_left": cache.tensors["feat_left"][:4],
             "feat_right": cache.tensors["feat_right"][:4]}
    with torch.no_grad():
        assert torch.allclose(net(obs), net(feats), atol=1e-5)


def test_relative_targets_are_learnt_from_the_measured_state_and_rolled_out_absolute(demos, tmp_path):
    """``pose``/``opening`` = "relative": the network learns the target's displacement and rotation from the
    measured pose (holding still is zero) and the commanded width minus the measured one (on Pull-out Key
    the held grasp is a squeeze of 1.4 mm, whatever width the bow stops the fingers at); the rollout adds
    the state measured when the chunk is predicted back, so the environment still gets absolute targets."""
    i, j, k = torch.eye(4)[1], torch.eye(4)[2], torch.eye(4)[3]
    assert torch.equal(quat_mul(i, j), k) and torch.equal(quat_mul(j, i), -k)
    t = demos.tensors
    relative = tiny_config(pose="relative", opening="relative")
    targets = chunk_targets(t["agent_pos"], t["action"], relative)
    agent, actions = t["agent_pos"], t["action"]
    assert torch.allclose(targets[..., :3], actions[..., :3] - agent[:, None, :3])
    assert torch.allclose(targets[..., 7], actions[..., 7] - agent[:, None, 7])
    assert (targets[..., 3] >= 0).all()
    # a target equal to the measured pose is the identity: holding still is zero
    still = chunk_targets(agent, agent[:, None].repeat(1, 2, 1), relative)
    assert torch.allclose(still[..., :3], torch.zeros(1)) and torch.allclose(still[..., 7], torch.zeros(1))
    assert torch.allclose(still[..., 3:7].abs(), torch.tensor([1.0, 0.0, 0.0, 0.0]), atol=1e-6)
    assert chunk_targets(agent, actions, tiny_config()) is actions
    only_opening = chunk_targets(agent, actions, tiny_config(opening="relative"))
    assert torch.equal(only_opening[..., :7], actions[..., :7])
    squeeze_mm = 1e3 * np.median(only_opening[..., 7][~t["action_is_pad"]].numpy())
    assert -1.5 < squeeze_mm < -1.3  # the expert's hold: 1.4 mm inside the stalled fingers
    for n in (0, len(agent) // 2, len(agent) - 1):  # absolute_chunk inverts chunk_targets
        back = absolute_chunk(targets[n].numpy(), agent[n].numpy(), relative)
        want = actions[n].numpy()
        assert np.allclose(back[:, :3], want[:, :3], atol=1e-6) and np.allclose(back[:, 7], want[:, 7], atol=1e-6)
        assert np.allclose(np.abs((back[:, 3:7] * want[:, 3:7]).sum(1)), 1.0, atol=1e-5)  # the same rotation

    torch.set_num_threads(1)
    net, norm, _ = train(demos, relative, steps=3, batch_size=8, lr=1e-3, seed=0, shift_px=0, log=lambda _: None)
    assert abs(norm.action_mean[7].item()) < 5e-3  # fitted on squeezes (mm), not on widths
    save_checkpoint(tmp_path / "policy.pt", net, norm)
    again, norm2, _ = load_checkpoint(tmp_path / "policy.pt")
    assert (again.config.pose, again.config.opening) == ("relative", "relative")
    env = TaskEnv(TASK, cameras=False, rate_hz=10.0)
    obs, _ = env.reset(seed=1_000_000)
    env.close()
    policy = ChunkPolicy(again, norm2)
    with torch.no_grad():
        raw = (again(policy.observation(obs))[0] * norm2.action_std + norm2.action_mean).numpy()
    got = policy.predict_chunk(obs)
    assert np.allclose(got, absolute_chunk(raw, obs["agent_pos"], again.config))
    assert np.allclose(got[:, :3], raw[:, :3] + obs["agent_pos"][:3], atol=1e-6)
    assert np.allclose(got[:, 7], raw[:, 7] + obs["agent_pos"][7], atol=1e-6)
    # checkpoints written before the options existed are absolute
    old = {k: v for k, v in tiny_config().to_dict().items() if k not in ("pose", "opening")}
    assert (PolicyConfig.from_dict(old).pose, PolicyConfig.from_dict(old).opening) == ("absolute", "absolute")
    for bad in ({"opening": "delta"}, {"pose": "local"}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            tiny_config(**bad)


def recorded_observation(episode, frame: int) -> dict:
    """What TaskEnv(cameras=False, tactile_extras=True) observes, rebuilt from a recorded frame."""
    agent = np.concatenate([episode["robot/ee_pose"][frame], [episode["robot/gripper_width_m"][frame]]])
    pixels, extras = {}, {}
    for pad in ("left", "right"):
        pixels[f"tactile_{pad}"] = episode[f"tactile/{pad}/marked_rgb"][frame]
        extras[f"{pad}_depth_mm"] = episode[f"tactile/{pad}/depth_um"][frame].astype(np.float32) / 1000.0
        extras[f"{pad}_force_n"] = np.array([episode[f"tactile/{pad}/normal_force_n"][frame],
                                             *episode[f"tactile/{pad}/shear_force_n"][frame]], np.float32)
    return {"pixels": pixels, "agent_pos": agent.astype(np.float32), "tactile": extras}


def test_history_is_read_the_same_in_training_and_at_rollout(corpus, tmp_path):
    """``history`` H: the network reads the past H policy steps of agent_pos and (tactile variants) the
    pads' touch signals. Training takes them from the rows one policy step apart in the same episode, the
    episode's first frame standing in before it starts; the rollout keeps them in ``ChunkPolicy`` and
    pads its first steps with the first observation. Both must give the network the same numbers."""
    root, episode = corpus
    config = tiny_config(history=3)
    demos = load_demos(root, TASK, config, stride=1, log=lambda _: None)
    t = demos.tensors
    frames = [0, 40, len(t["agent_pos"]) - 1]
    for frame in frames:  # the touch signals are the recorded depth and forces
        want = touch_signals(recorded_observation(episode, frame))
        assert np.allclose(t["touch"][frame].numpy(), want, atol=1e-6)
    assert t["touch"][:, :, 0].max() > 0.3  # the key is gripped to 0.5 mm: the signal is there
    rows = history_rows(torch.tensor([0, 0, 0, 0, 0, 0, 0, 1, 1, 1]), 2, 2)
    # two steps back, two rows a step, oldest first; nothing reaches into the previous episode
    assert rows.tolist() == [[0, 0], [0, 0], [0, 0], [0, 1], [0, 2], [1, 3], [2, 4], [7, 7], [7, 7], [7, 7]]

    torch.set_num_threads(1)
    net, norm, losses = train(demos, config, steps=3, batch_size=8, lr=1e-3, seed=0, shift_px=0, log=lambda _: None)
    assert np.isfinite(losses).all()
    targets = chunk_targets(t["agent_pos"], t["action"], config)
    policy = ChunkPolicy(net, norm)
    policy.reset()
    step = demos.subsample  # recorded frames a policy step
    for k, frame in enumerate(range(0, 8 * step, step)):
        obs = recorded_observation(episode, frame)
        batch, _, _ = make_batch(demos, targets, torch.tensor([frame]), norm, config, 0, None)
        rollout = policy.observation(obs)
        for key in ("agent_pos", "past_agent", "touch", "tactile_left"):
            assert torch.allclose(rollout[key], batch[key], atol=1e-5), (k, key)
        policy.act(obs)
    assert not torch.equal(rollout["past_agent"][0, 0], rollout["past_agent"][0, -1])  # it did move
    with pytest.raises(ValueError, match="stride 1"):
        train(load_demos(root, TASK, config, stride=3, log=lambda _: None), config, steps=1, batch_size=2, lr=1e-3,
              seed=0, log=lambda _: None)
    with pytest.raises(ValueError, match="history"):
        tiny_config(history=-1)
    with pytest.raises(KeyError, match="--tactile-extras"):
        policy.observation({**obs, "tactile": None})
    # a vision policy reads its past agent_pos only: no touch token, no tactile extras needed
    vision, vnorm, _ = train(demos, tiny_config("vision", history=3), steps=2, batch_size=8, lr=1e-3, seed=0,
                             shift_px=0, log=lambda _: None)
    assert vision.touch is None and vision.past_agent is not None
    blind = ChunkPolicy(vision, vnorm)
    bare_obs = {"pixels": {}, "agent_pos": obs["agent_pos"]}
    assert set(blind.observation(bare_obs)) == {"agent_pos", "past_agent"}
    assert blind.act(bare_obs).shape == (8,)

    # end to end: the rollout needs the pads' signals, so evaluate runs it with --tactile-extras
    save_checkpoint(tmp_path / "policy.pt", net, norm)
    env = {CHECKPOINT_ENV: str(tmp_path / "policy.pt")}
    common = ("evaluate", TASK, "--policy", "act_policy:from_env", "--episodes", "1", "--no-cameras", "--rate-hz", "10")
    run = cli(*common, "--tactile-extras", "--json", str(tmp_path / "eval.json"), extra_env=env)
    assert run.returncode == 0, run.stderr
    report = json.loads((tmp_path / "eval.json").read_text())
    assert report["errors"] == 0 and report["per_rollout"][0]["steps"] >= 1, report["per_rollout"]
    without = cli(*common, "--json", str(tmp_path / "bare.json"), extra_env=env)
    assert without.returncode == 0, without.stderr
    (bare,) = json.loads((tmp_path / "bare.json").read_text())["per_rollout"]
    assert bare["reason"].startswith("error") and "--tactile-extras" in bare["reason"]


def test_train_refuses_history_it_cannot_read_in_one_line(tmp_path):
    script = str(EXAMPLES / "train_policy.py")
    common = [sys.executable, script, "train", "--data", str(tmp_path), "--task", TASK, "--variant", "vision",
              "--out", str(tmp_path / "run")]
    for extra, message in ((["--stride", "3"], "use --stride 1"), (["--history", "-2"], "--history must be >= 0")):
        run = subprocess.run(common + extra, capture_output=True, text=True, timeout=300)
        assert run.returncode != 0 and message in run.stderr and "Traceback" not in run.stderr, run.stderr
    assert not (tmp_path / "run").exists()  # refused before anything was written


def test_the_report_pools_training_seeds_and_gives_touch_an_interval():
    """Newcombe's (1998) worked example of his method 10: 56/70 against 48/80 is +0.2000 (0.0524 to 0.3338);
    and the report pools each variant's training seeds before comparing it with vision."""
    d, lo, hi = difference_interval(56, 70, 48, 80)
    assert np.allclose((d, lo, hi), (0.2, 0.0524, 0.3338), atol=2e-4)  # z = 1.96 against his 1.959964
    d, lo, hi = difference_interval(0, 50, 0, 50)
    assert d == 0.0 and lo < 0.0 < hi

    def row(variant: str, seed: int, k: int, n: int = 50) -> dict:
        return {"task": "grasp_classify", "variant": variant, "seed": seed, "rollouts": n, "successes": k,
                "success_rate": k / n, "unsafe_rate": 0.1, "train_s": 60.0, "eval_s": 30.0}

    rows = [row("vision", 0, 10), row("vision", 1, 20), row("vision_tactile", 0, 30), row("vision_tactile", 1, 25)]
    pooled = pooled_rows(rows)
    assert [(r["variant"], r["successes"], r["rollouts"], r["training_seeds"]) for r in pooled] == [
        ("vision", 30, 100, [0, 1]), ("vision_tactile", 55, 100, [0, 1])]
    assert pooled[0]["per_seed_success_rate"] == [0.2, 0.4]
    (effect,) = touch_effects(pooled)
    assert effect["variant"] == "vision_tactile" and abs(effect["points"] - 25.0) < 1e-9 and effect["goal_met"]
    lo, hi = effect["interval95_points"]
    assert 0.0 < lo < 25.0 < hi
    # runs trained on other targets are pooled apart and compared only with vision of their own recipe
    relative = [{**row("vision_tactile", 3, 50), "pose": "relative", "opening": "relative"}]
    pooled = pooled_rows(rows + relative)
    assert [(r["variant"], r["pose"], r["successes"]) for r in pooled] == [
        ("vision", "absolute", 30), ("vision_tactile", "absolute", 55), ("vision_tactile", "relative", 50)]
    assert len(touch_effects(pooled)) == 1
    # so are runs read with more history or rolled out with another ensembling weight
    others = [{**row("vision", 4, 5), "history": 25}, {**row("vision", 5, 5), "ensemble_k": -0.5}]
    pooled = pooled_rows(rows + others)
    assert [(r["history"], r["ensemble_k"], r["successes"]) for r in pooled if r["variant"] == "vision"] == [
        (0, 0.01, 30), (25, 0.01, 5), (0, -0.5, 5)]
    assert len(touch_effects(pooled)) == 1


def test_runs_on_other_demonstrations_are_neither_pooled_nor_compared():
    """A run records the fingerprint of its demonstrations: runs on other demonstrations (regenerated after an
    expert changed) pool apart, and touch is compared with vision on the same demonstrations only."""
    def row(variant: str, seed: int, k: int, demos: str | None) -> dict:
        out = {"task": "insert_tube", "variant": variant, "seed": seed, "rollouts": 50, "successes": k,
               "success_rate": k / 50, "unsafe_rate": 0.0, "train_s": 1.0, "eval_s": 1.0}
        return out if demos is None else {**out, "demonstrations_sha256": demos}

    rows = [row("vision", 0, 10, None), row("vision_encoder", 0, 40, None),
            row("vision", 0, 20, "aa"), row("vision", 1, 30, "aa"), row("vision_tactile", 0, 45, "aa")]
    pooled = pooled_rows(rows)
    assert [(r["variant"], r["demonstrations_sha256"], r["successes"]) for r in pooled] == [
        ("vision", None, 10), ("vision_encoder", None, 40), ("vision", "aa", 50), ("vision_tactile", "aa", 45)]
    effects = {(e["variant"], e["demonstrations_sha256"]): e["points"] for e in touch_effects(pooled)}
    assert effects == pytest.approx({("vision_encoder", None): 60.0, ("vision_tactile", "aa"): 40.0})


def test_the_demonstrations_fingerprint_reads_seeds_and_actions_only(corpus, tmp_path, capsys):
    """The same demonstrations give the same fingerprint in either backend; one changed action or another seed
    changes it; a path without the task's episodes is one clear error."""
    from dataclasses import replace

    from train_policy import demonstrations_sha256

    root, episode = corpus
    sha, n = demonstrations_sha256(root, TASK)
    assert n == 1 and len(sha) == 64
    assert train_policy_main(["fingerprint", "--data", str(root), "--task", TASK]) == 0
    assert capsys.readouterr().out.startswith(sha)
    as_zarr = tmp_path / "zarr"
    DatasetWriter.open(as_zarr, storage="zarr").add(episode)
    assert demonstrations_sha256(as_zarr, TASK) == (sha, 1)

    nudged = dict(episode.arrays)
    nudged["robot/action"] = episode["robot/action"].copy()
    nudged["robot/action"][5, 0] += 1e-6  # m
    changed = tmp_path / "changed"
    DatasetWriter.open(changed).add(replace(episode, arrays=nudged))
    assert demonstrations_sha256(changed, TASK)[0] != sha
    reseeded = tmp_path / "reseeded"
    DatasetWriter.open(reseeded).add(replace(episode, meta=episode.meta.model_copy(update={"seed": 7})))
    assert demonstrations_sha256(reseeded, TASK)[0] != sha
    both = tmp_path / "both"  # seeds 7 and 0: seed order, and --max-episodes reads the first
    with DatasetWriter.open(both) as writer:
        writer.add(replace(episode, meta=episode.meta.model_copy(
            update={"seed": 7, "episode_id": episode.meta.episode_id.replace("000000", "000007")})))
        writer.add(episode)
    assert demonstrations_sha256(both, TASK)[1] == 2 and demonstrations_sha256(both, TASK)[0] != sha
    assert demonstrations_sha256(both, TASK, max_episodes=1) == (sha, 1)

    with pytest.raises(SystemExit, match=f"{root}: no episode of task 'lift_can'"):
        demonstrations_sha256(root, "lift_can")
    with pytest.raises(SystemExit, match="missing"):
        demonstrations_sha256(tmp_path / "missing", TASK)


def test_a_cache_of_other_demonstrations_in_the_same_directory_is_read_again(corpus, tmp_path):
    """Demonstrations regenerated into the directory a cache was made from are read again, not served from
    the cache; an unreadable cache is read again too."""
    import shutil
    from dataclasses import replace

    from train_policy import cached_demos

    _, episode = corpus
    data, cache_file = tmp_path / "data", tmp_path / "cache.pt"
    DatasetWriter.open(data).add(episode)
    messages: list[str] = []
    first = cached_demos(str(cache_file), str(data), TASK, tiny_config(), 3, None, log=messages.append)
    again = cached_demos(str(cache_file), str(data), TASK, tiny_config(), 3, None, log=messages.append)
    assert any("samples from the cache" in m for m in messages)
    assert torch.equal(first.tensors["action"], again.tensors["action"])

    shutil.rmtree(data)  # the same seed regenerated with one action 1 mm further
    nudged = dict(episode.arrays)
    nudged["robot/action"] = episode["robot/action"].copy()
    nudged["robot/action"][:, 0] += 1e-3  # m
    DatasetWriter.open(data).add(replace(episode, arrays=nudged))
    messages.clear()
    regenerated = cached_demos(str(cache_file), str(data), TASK, tiny_config(), 3, None, log=messages.append)
    assert any("made from other demonstrations" in m for m in messages)
    assert not torch.equal(regenerated.tensors["action"], first.tensors["action"])

    cache_file.write_bytes(cache_file.read_bytes()[:100])  # cut short
    messages.clear()
    reread = cached_demos(str(cache_file), str(data), TASK, tiny_config(), 3, None, log=messages.append)
    assert any("unreadable" in m for m in messages)
    assert torch.equal(reread.tensors["action"], regenerated.tensors["action"])


def test_the_chart_wraps_many_tasks_onto_panels(tmp_path):
    """Up to five task groups fit one panel; more wrap onto another (the figure grows taller, not wider)."""
    from PIL import Image

    def pooled(tasks: int) -> list[dict]:
        rows = [{"task": f"task{t}", "variant": v, "seed": 0, "rollouts": 10, "successes": 3 + t,
                 "success_rate": (3 + t) / 10, "unsafe_rate": 0.0, "train_s": 1.0, "eval_s": 1.0}
                for t in range(tasks) for v in ("vision", "vision_tactile")]
        return pooled_rows(rows)

    chart(pooled(5), tmp_path / "five.png")
    chart(pooled(7), tmp_path / "seven.png")
    with Image.open(tmp_path / "five.png") as five, Image.open(tmp_path / "seven.png") as seven:
        (w5, h5), (w7, h7) = five.size, seven.size
    assert w7 == w5 and h7 > 1.8 * h5


def test_report_merge_keeps_earlier_rows_and_replaces_a_rerun(tmp_path, capsys):
    """``report --merge``: the earlier report's rows (runs whose directories are gone), setup and ablations stay;
    a run of the same task, variant, seed and recipe replaces its earlier row; a bad file is one clear error."""
    def run_dir(name: str, task: str, variant: str, seed: int, wins: int) -> Path:
        run = tmp_path / name
        run.mkdir()
        (run / "train.json").write_text(json.dumps({
            "task": task, "variant": variant, "demos": 2, "rate_hz": 25.0, "demo_rate_hz": 25.0, "chunk": 4,
            "steps": 3, "epochs": 1.0, "batch_size": 2, "samples": 10, "trainable_parameters": 5, "read_s": 0.1,
            "train_s": 1.0, "loss_first_100": 1.0, "loss_last_100": 0.5, "camera_size": "128x72", "seed": seed,
            "pose": "relative", "opening": "relative", "history": 25}))
        rollouts = [{"seed": 1_000_000 + i, "success": i < wins, "unsafe": False,
                     "reason": "success" if i < wins else "step_limit", "steps": 9} for i in range(4)]
        (run / "eval.json").write_text(json.dumps({"per_rollout": rollouts, "ensemble_k": 0.01, "wall_s": 1.0}))
        return run

    first = [run_dir("a", "insert_hdmi", "vision", 0, 1), run_dir("b", "insert_hdmi", "vision_tactile", 0, 3)]
    earlier = tmp_path / "earlier.json"
    assert train_policy_main(["report", "--runs", *map(str, first), "--json", str(earlier), "--note", "round 1"]) == 0
    report = json.loads(earlier.read_text())
    report["setup"] = {"demonstrations": {"insert_hdmi": {"episodes": 2}}}
    report["ablations"] = [{"note": "old recipe", "rows": []}]
    earlier.write_text(json.dumps(report))

    added = run_dir("c", "lift_can", "vision", 0, 2)
    rerun = run_dir("d", "insert_hdmi", "vision", 0, 4)  # the same run as "a", evaluated again
    merged = tmp_path / "merged.json"
    assert train_policy_main(["report", "--runs", str(added), str(rerun), "--merge", str(earlier),
                              "--json", str(merged)]) == 0
    out = json.loads(merged.read_text())
    assert [(r["task"], r["variant"], r["successes"]) for r in out["rows"]] == [
        ("insert_hdmi", "vision", 4), ("insert_hdmi", "vision_tactile", 3), ("lift_can", "vision", 2)]
    assert out["note"] == "round 1" and out["setup"] == report["setup"] and out["ablations"] == report["ablations"]
    assert [(e["task"], e["points"]) for e in out["touch_effects"]] == [("insert_hdmi", -25.0)]
    capsys.readouterr()

    (tmp_path / "broken.json").write_text('{"rows": ')
    with pytest.raises(SystemExit, match="--merge .*broken.json: not a readable JSON file"):
        train_policy_main(["report", "--runs", str(added), "--merge", str(tmp_path / "broken.json"),
                           "--json", str(tmp_path / "x.json")])
    (tmp_path / "other.json").write_text('{"per_rollout": []}')
    with pytest.raises(SystemExit, match="no 'rows' list"):
        train_policy_main(["report", "--runs", str(added), "--merge", str(tmp_path / "other.json"),
                           "--json", str(tmp_path / "x.json")])
    assert not (tmp_path / "x.json").exists()


def test_a_run_merges_only_evaluations_made_alike(tmp_path):
    def evaluation(name: str, first_seed: int, k: float) -> None:
        rollouts = [{"seed": first_seed + i, "success": i % 2 == 0, "unsafe": False, "reason": "success", "steps": 9}
                    for i in range(4)]
        (tmp_path / name).write_text(json.dumps({"per_rollout": rollouts, "ensemble_k": k, "wall_s": 1.0}))

    evaluation("eval.json", 1_000_000, 0.01)
    evaluation("eval-4.json", 1_000_004, 0.01)
    merged = merged_evaluation(tmp_path)
    assert (merged["rollouts"], merged["successes"], merged["ensemble_k"]) == (8, 4, 0.01)
    evaluation("eval-8.json", 1_000_008, -0.5)
    with pytest.raises(SystemExit, match="ensemble-k"):
        merged_evaluation(tmp_path)
    evaluation("eval-8.json", 1_000_002, 0.01)
    with pytest.raises(SystemExit, match="overlap"):
        merged_evaluation(tmp_path)


def test_rate_hz_keeps_the_step_limit_as_a_time_limit(tmp_path):
    env = TaskEnv(TASK, cameras=False, rate_hz=10.0)
    assert step_limit(env) == 60  # 300 steps at 50 Hz: 6 s
    env.close()
    run = cli("evaluate", TASK, "--policy", "zero", "--episodes", "1", "--no-cameras", "--rate-hz", "10",
              "--json", str(tmp_path / "zero.json"))
    assert run.returncode == 0, run.stderr
    report = json.loads((tmp_path / "zero.json").read_text())
    assert report["per_rollout"][0]["steps"] == 60 and report["per_rollout"][0]["reason"] == "step_limit"
    bad = cli("evaluate", TASK, "--policy", "zero", "--episodes", "1", "--no-cameras", "--rate-hz", "7")
    assert bad.returncode != 0 and "--rate-hz" in bad.stderr


def test_a_trained_policy_runs_through_univtac_data_evaluate(trained, tmp_path):
    net, norm, _ = trained
    save_checkpoint(tmp_path / "policy.pt", net, norm)
    out = tmp_path / "eval.json"
    run = cli("evaluate", TASK, "--policy", "act_policy:from_env", "--episodes", "1", "--no-cameras",
              "--rate-hz", "10", "--json", str(out), extra_env={CHECKPOINT_ENV: str(tmp_path / "policy.pt")})
    assert run.returncode == 0, run.stderr
    report = json.loads(out.read_text())
    assert report["rollouts"] == 1 and report["errors"] == 0, report["per_rollout"]
    assert 1 <= report["per_rollout"][0]["steps"] <= 60
    newest = cli("evaluate", TASK, "--policy", "act_policy:from_env", "--episodes", "1", "--no-cameras",
                 "--rate-hz", "10", extra_env={CHECKPOINT_ENV: str(tmp_path / "policy.pt"),
                                               "UNIVTAC_POLICY_ENSEMBLE_K": "-10"})
    assert newest.returncode == 0 and "errors 0" in newest.stdout, newest.stderr
    missing = cli("evaluate", TASK, "--policy", "act_policy:from_env", "--episodes", "1", "--no-cameras",
                  extra_env={CHECKPOINT_ENV: ""})
    assert missing.returncode != 0 and CHECKPOINT_ENV in missing.stderr


def cli(*args: str, extra_env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "MUJOCO_GL": "egl", **(extra_env or {})}
    env["PYTHONPATH"] = str(EXAMPLES) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-m", "univtac_data.cli.main", *args], capture_output=True, text=True,
                          timeout=600, env=env)
