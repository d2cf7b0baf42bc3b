"""A small ACT-style action-chunking policy in plain torch, and its runtime for ``univtac-data evaluate``.

The network (``ChunkPolicyNet``) reads one observation and predicts the next ``chunk`` actions (x, y, z m;
quaternion w, x, y, z; opening m; absolute, or with ``PolicyConfig.pose``/``opening`` = "relative" taken
from the pose and opening measured when the chunk is predicted (``chunk_targets``); all normalised by the
demonstrations' mean and std), as ACT
does without its CVAE: a transformer encoder over observation tokens, a transformer decoder with one learned
query per action of the chunk. Tokens:

* ``agent_pos`` (8,): one token (the end-effector pose in the world and the opening, normalised);
* cameras (``head``, ``wrist``, RGB, recorded at 128 x 72 px, area-resized to 64 x 36 px: two CPU cores
  train a bigger image network too slowly): a small CNN per camera, stride 16, one token per cell of its
  3 x 4 feature map, with a learned position embedding;
* tactile, by variant: ``vision`` none; ``vision_tactile`` each pad's marked image (area-resized to
  48 x 64 px) through a small CNN trained end to end, one token per pad; ``vision_encoder`` the same images
  through the pretrained ``TactileEncoder`` (``examples/tactile_encoder.py``), frozen, its features per pad
  (128, or 256 with the recipe's average+maximum pooling) projected to one token;
* with ``PolicyConfig.history`` H > 0, the past: one token of the last H steps' agent_pos relative to now
  (every variant), and for the tactile variants one more of both pads' ``TOUCH_SIGNALS`` (deepest
  indentation mm, normal and shear force N) over those steps and now. The rollout then needs
  ``univtac-data evaluate --tactile-extras``: the signals are the environment's, as recorded in the episodes.

Training minimises the L1 distance to the demonstrated chunk over the actions that exist: ``action_is_pad``
(past the episode's end) is masked out of the loss (``masked_l1``). At rollout the policy predicts a chunk
every step and averages every prediction made for the current step with weights exp(-k i), i = 0 the
oldest (ACT's temporal ensembling, ``TemporalEnsembler``). ACT's k = 0.01 weighs the 20 predictions almost
alike, so a contact the pads feel turns the action round only after about ten steps; a negative k weighs
the newest most (``train_policy.py train --ensemble-k``, stored as ``config.ensemble_k``).

``univtac-data evaluate TASK --policy act_policy:from_env`` (with ``examples/`` on ``PYTHONPATH``) loads
the checkpoint named by the environment variable ``UNIVTAC_POLICY_CHECKPOINT``; evaluate at the rate the
policy was trained at (``--rate-hz``, stored in the checkpoint as ``config.rate_hz``) and with the camera
size it was trained on. ``examples/train_policy.py`` trains, evaluates and reports.
"""

from __future__ import annotations

import os
from collections import deque
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

VARIANTS = ("vision", "vision_tactile", "vision_encoder")
TARGET_FRAMES = ("absolute", "relative")
PADS = ("left", "right")
CHECKPOINT_ENV = "UNIVTAC_POLICY_CHECKPOINT"
ENSEMBLE_K_ENV = "UNIVTAC_POLICY_ENSEMBLE_K"


@dataclass(frozen=True)
class PolicyConfig:
    """Architecture and rollout settings, saved with the checkpoint."""

    variant: str = "vision"
    cameras: tuple[str, ...] = ("head", "wrist")
    camera_hw: tuple[int, int] = (36, 64)     # height, width px the camera CNN reads (area-resized)
    camera_widths: tuple[int, ...] = (16, 32, 32, 64)  # channels of the camera CNN's four stride-2 stages
    tactile_hw: tuple[int, int] = (48, 64)    # height, width px of each pad's image (the encoder's input)
    chunk: int = 20                            # actions predicted per step (0.8 s at 25 Hz)
    rate_hz: float = 25.0                      # policy steps a second the chunk is spaced at
    d_model: int = 128
    heads: int = 4
    encoder_layers: int = 2
    decoder_layers: int = 2
    feedforward: int = 512
    dropout: float = 0.1
    ensemble_k: float = 0.01                   # temporal-ensembling weight exp(-k i), i = 0 the oldest
    # what a chunk's pose columns are: "absolute" (the end-effector target in the world) or "relative" (the
    # target's displacement from the pose measured when the chunk is predicted, m, and its rotation from it,
    # a world-frame quaternion q_target q_now^-1 with w >= 0); and its opening column: "absolute" (the
    # commanded width, m) or "relative" (minus the opening measured then). Checkpoints without them are absolute.
    pose: str = "absolute"
    opening: str = "absolute"
    # policy steps of the past the network reads besides the present (0: the present only): every variant
    # one token of its past agent_pos (relative to now), the tactile variants one more of the pads' touch
    # signals (``TOUCH_SIGNALS``) over those steps and now. A reactive policy cannot tell "turning towards the
    # stop" from "turned back from it"; the key's stop shows on the pads for 3 steps of 25 Hz.
    history: int = 0
    encoder: dict[str, Any] | None = field(default=None)  # EncoderConfig of the frozen encoder (vision_encoder)

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise ValueError(f"variant must be one of {', '.join(VARIANTS)} (got {self.variant!r})")
        for name in ("pose", "opening"):
            if getattr(self, name) not in TARGET_FRAMES:
                raise ValueError(f"{name} must be one of {', '.join(TARGET_FRAMES)} (got {getattr(self, name)!r})")
        if self.history < 0:
            raise ValueError(f"history must be >= 0 policy steps (got {self.history})")
        if self.variant == "vision_encoder" and self.encoder is None:
            raise ValueError("the vision_encoder variant needs the encoder's config (load it with --encoder PATH)")
        if self.variant == "vision_encoder" and self.encoder is not None:
            size = (int(self.encoder.get("height", 48)), int(self.encoder.get("width", 64)))
            if size != tuple(self.tactile_hw):  # resized to another size, the features would mean something else
                raise ValueError(f"tactile_hw {tuple(self.tactile_hw)} must be the encoder's input size {size}")

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "cameras": list(self.cameras), "camera_hw": list(self.camera_hw),
                "camera_widths": list(self.camera_widths), "tactile_hw": list(self.tactile_hw)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> PolicyConfig:
        return cls(**{**data, "cameras": tuple(data["cameras"]), "camera_hw": tuple(data["camera_hw"]),
                      "camera_widths": tuple(data["camera_widths"]), "tactile_hw": tuple(data["tactile_hw"])})

    @property
    def uses_tactile(self) -> bool:
        return self.variant != "vision"

    @property
    def reads_touch(self) -> bool:
        """Whether the network reads the pads' touch signals (a tactile variant with history)."""
        return self.uses_tactile and self.history > 0


# ----------------------------------------------------------------------------------------- preprocessing

def resize_uint8(images: torch.Tensor, hw: tuple[int, int]) -> torch.Tensor:
    """(B, 3, H, W) uint8 -> (B, 3, h, w) uint8, area-averaged (as the encoder's corpus was made); the
    same function prepares training samples and rollout observations."""
    if tuple(images.shape[-2:]) == tuple(hw):
        return images
    return F.interpolate(images.float(), size=hw, mode="area").round().clamp(0, 255).to(torch.uint8)


def hwc_to_chw(array: np.ndarray) -> torch.Tensor:
    """(H, W, 3) uint8 observation -> (1, 3, H, W) uint8 tensor."""
    return torch.from_numpy(np.ascontiguousarray(array)).permute(2, 0, 1)[None]


# Smallest std per component of agent_pos and of an action (x, y, z m; quaternion w, x, y, z; opening m):
# a component that hardly moves (a quaternion component of a top-down task) must not turn a tiny deviation
# at test time into a huge input. The floor is in each component's unit: 1 mm for positions and the
# opening, 0.01 for quaternion components. One 0.01 floor for all (the first recipe) normalised Pull-out
# Key's opening (std 1.5 mm) and x, y (2.7-2.9 mm) by 10 mm: a normalised L1 of 0.06 was then 0.6 mm of
# opening, and the opening the policy reads in agent_pos moved 0.05 between free and touching.
STD_FLOOR = (1e-3, 1e-3, 1e-3, 1e-2, 1e-2, 1e-2, 1e-2, 1e-3)


# What a pad's touch signals are, per step (``touch_signals``), and the scale each is divided by for the
# network: the deepest indentation (mm; the key's expert grasps to 0.5 mm and feels its stop as a rise over
# 0.12 mm), the normal force and the two shear components in the pad frame (N).
TOUCH_SIGNALS = ("max_depth_mm", "normal_force_n", "shear_x_n", "shear_y_n")
TOUCH_SCALE = (0.5, 5.0, 1.0, 1.0)


def touch_signals(obs: dict[str, Any]) -> np.ndarray:
    """(2, 4) float32 ``TOUCH_SIGNALS`` of both pads (left, right) from an environment observation made with
    ``tactile_extras`` (``univtac-data evaluate --tactile-extras``)."""
    extras = obs.get("tactile")
    if extras is None:
        raise KeyError("the policy reads the pads' touch signals: evaluate with --tactile-extras")
    return np.array([[float(np.max(extras[f"{pad}_depth_mm"])), *np.asarray(extras[f"{pad}_force_n"], np.float64)]
                     for pad in PADS], np.float32)


OPENING = 7  # the opening's column in agent_pos and in an action
QUAT = slice(3, 7)  # the quaternion's columns (w, x, y, z)


def quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product of quaternions (..., 4) w, x, y, z (broadcasting)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                        aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], -1)


def chunk_targets(agent_pos: torch.Tensor, actions: torch.Tensor, config: PolicyConfig) -> torch.Tensor:
    """Recorded absolute actions (N, C, 8) -> what the network learns to predict, given the state measured when
    each chunk starts, ``agent_pos`` (N, 8). ``pose="relative"``: the target's displacement (m) and rotation
    (q_target q_now^-1, sign chosen with w >= 0) from the measured pose, so holding still is zero, whatever
    the scene's layout; an absolute target makes the network rebuild the pose it reads from its input, and
    with 50 demonstrations it regresses towards their mean (Grasp Classify's first policies drifted 14 mm
    off the cylinder they started above, then came down on its top). ``opening="relative"``: the commanded
    width minus the measured one, so a held grasp is a squeeze of about -1.4 mm whatever the object's width."""
    if config.pose == "absolute" and config.opening == "absolute":
        return actions
    targets = actions.clone()
    now = agent_pos[:, None]
    if config.pose == "relative":
        targets[..., :3] -= now[..., :3]
        conj = now[..., QUAT] * torch.tensor([1.0, -1.0, -1.0, -1.0], dtype=now.dtype)
        rotation = quat_mul(actions[..., QUAT], conj)
        targets[..., QUAT] = torch.where(rotation[..., :1] < 0, -rotation, rotation)
    if config.opening == "relative":
        targets[..., OPENING] -= now[..., OPENING]
    return targets


def absolute_chunk(chunk: np.ndarray, agent_pos: np.ndarray, config: PolicyConfig) -> np.ndarray:
    """The inverse of ``chunk_targets`` at rollout: a predicted (C, 8) chunk -> absolute actions."""
    if config.pose == "absolute" and config.opening == "absolute":
        return chunk
    out = np.array(chunk, dtype=np.float64, copy=True)
    now = np.asarray(agent_pos, np.float64)
    if config.pose == "relative":
        out[:, :3] += now[:3]
        out[:, QUAT] = quat_mul(torch.from_numpy(out[:, QUAT]), torch.from_numpy(now[QUAT])[None]).numpy()
    if config.opening == "relative":
        out[:, OPENING] += now[OPENING]
    return out


@dataclass
class Normalization:
    """Per-component mean and std (float32) of agent_pos (8,) and of the actions (8,); each std floored at
    ``STD_FLOOR`` (in the component's unit)."""

    agent_mean: torch.Tensor
    agent_std: torch.Tensor
    action_mean: torch.Tensor
    action_std: torch.Tensor

    @classmethod
    def fit(cls, agent_pos: torch.Tensor, actions: torch.Tensor, is_pad: torch.Tensor,
            floor: tuple[float, ...] = STD_FLOOR) -> Normalization:
        real = actions[~is_pad]
        low = torch.tensor(floor, dtype=agent_pos.dtype)
        return cls(agent_pos.mean(0), torch.maximum(agent_pos.std(0), low), real.mean(0),
                   torch.maximum(real.std(0), low))

    def to_dict(self) -> dict[str, list[float]]:
        return {k: v.tolist() for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict[str, list[float]]) -> Normalization:
        return cls(**{k: torch.tensor(v, dtype=torch.float32) for k, v in data.items()})


# ---------------------------------------------------------------------------------------------- network

def conv_gn(c_in: int, c_out: int, kernel: int, stride: int) -> nn.Sequential:
    # GroupNorm, not BatchNorm: the same arithmetic in training and at rollout (batch of one)
    return nn.Sequential(nn.Conv2d(c_in, c_out, kernel, stride, kernel // 2, bias=False), nn.GroupNorm(8, c_out),
                         nn.ReLU(inplace=True))


class CameraCNN(nn.Module):
    """(B, 3, H, W) in [0, 1] -> (B, H/16 * W/16, d) tokens (3 x 4 at 36 x 64 px) with a learned position
    embedding."""

    def __init__(self, hw: tuple[int, int], widths: tuple[int, ...], d_model: int) -> None:
        super().__init__()
        layers, c_in = [], 3
        for k, c in enumerate(widths):
            layers.append(conv_gn(c_in, c, 5 if k == 0 else 3, 2))
            c_in = c
        self.net = nn.Sequential(*layers, nn.Conv2d(c_in, d_model, 1))
        with torch.no_grad():
            n = self.net(torch.zeros(1, 3, *hw)).flatten(2).shape[-1]
        self.position = nn.Parameter(torch.randn(1, n, d_model) * 0.02)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return self.net(image - 0.5).flatten(2).transpose(1, 2) + self.position


class TactileCNN(nn.Module):
    """(B, 3, 48, 64) in [0, 1] -> (B, d): a pad's marked image to one token (trained end to end)."""

    def __init__(self, d_model: int) -> None:
        super().__init__()
        self.net = nn.Sequential(conv_gn(3, 16, 3, 2), conv_gn(16, 32, 3, 2), conv_gn(32, 64, 3, 2),
                                 conv_gn(64, 64, 3, 2))
        self.out = nn.Linear(64, d_model)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return self.out(F.adaptive_avg_pool2d(self.net(image - 0.5), 1).flatten(1))


class ChunkPolicyNet(nn.Module):
    """Observation -> (B, chunk, 8) normalised actions (see the module docstring)."""

    def __init__(self, config: PolicyConfig) -> None:
        super().__init__()
        self.config = config
        d = config.d_model
        self.agent = nn.Linear(8, d)
        self.cameras = nn.ModuleDict({name: CameraCNN(config.camera_hw, config.camera_widths, d) for name in config.cameras})
        self.tactile_cnn = TactileCNN(d) if config.variant == "vision_tactile" else None
        self.encoder: nn.Module | None = None
        self.encoder_proj: nn.Module | None = None
        if config.variant == "vision_encoder":
            from tactile_encoder import EncoderConfig, TactileEncoder

            assert config.encoder is not None
            enc = dict(config.encoder)
            enc["widths"] = tuple(enc["widths"])
            self.encoder = TactileEncoder(EncoderConfig(**enc)).eval()
            self.encoder.requires_grad_(False)
            feat = self.encoder.config.feature_dim
            self.encoder_proj = nn.Sequential(nn.LayerNorm(feat), nn.Linear(feat, d))
        n_tactile = len(PADS) if config.uses_tactile else 0
        self.past_agent: nn.Module | None = None
        self.touch: nn.Module | None = None
        if config.history:
            self.past_agent = nn.Sequential(nn.Linear(config.history * 8, d), nn.ReLU(), nn.Linear(d, d))
            if config.reads_touch:
                width = (config.history + 1) * len(PADS) * len(TOUCH_SIGNALS)
                self.touch = nn.Sequential(nn.Linear(width, d), nn.ReLU(), nn.Linear(d, d))
        n_history = (self.past_agent is not None) + (self.touch is not None)
        # agent, each pad, then the past agent_pos and the touch signals
        self.type_embedding = nn.Parameter(torch.randn(1 + n_tactile + n_history, d) * 0.02)
        layer = dict(d_model=d, nhead=config.heads, dim_feedforward=config.feedforward, dropout=config.dropout,
                     batch_first=True, norm_first=True)
        self.transformer_encoder = nn.TransformerEncoder(nn.TransformerEncoderLayer(**layer), config.encoder_layers,
                                                         enable_nested_tensor=False)
        self.transformer_decoder = nn.TransformerDecoder(nn.TransformerDecoderLayer(**layer), config.decoder_layers)
        self.queries = nn.Parameter(torch.randn(1, config.chunk, d) * 0.02)
        self.head = nn.Linear(d, 8)

    def train(self, mode: bool = True) -> ChunkPolicyNet:
        super().train(mode)
        if self.encoder is not None:  # frozen: its BatchNorm statistics stay the pretrained ones
            self.encoder.eval()
        return self

    def encoder_features(self, images: torch.Tensor) -> torch.Tensor:
        """(B, 3, 48, 64) in [0, 1] -> (B, F) frozen encoder features (no gradient)."""
        assert self.encoder is not None
        self.encoder.eval()  # whatever mode the policy is in: BatchNorm must not learn from policy data
        with torch.no_grad():
            return self.encoder.encode(images)

    def forward(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        """``obs``: ``agent_pos`` (B, 8) normalised; each camera (B, 3, h, w) in [0, 1]; for the tactile
        variants ``tactile_left``/``tactile_right`` (B, 3, 48, 64) in [0, 1], or for ``vision_encoder``
        precomputed ``feat_left``/``feat_right`` (B, F) instead of the images; with ``history`` H > 0 also
        ``past_agent`` (B, H, 8) (``past_agent_input``) and for the tactile variants ``touch``
        (B, H + 1, 2, 4) (``touch_input``)."""
        tokens = [(self.agent(obs["agent_pos"]) + self.type_embedding[0])[:, None]]
        for k, pad in enumerate(PADS if self.config.uses_tactile else ()):
            if self.tactile_cnn is not None:
                token = self.tactile_cnn(obs[f"tactile_{pad}"])
            else:
                assert self.encoder_proj is not None
                feat = obs.get(f"feat_{pad}")
                if feat is None:
                    feat = self.encoder_features(obs[f"tactile_{pad}"])
                token = self.encoder_proj(feat)
            tokens.append((token + self.type_embedding[1 + k])[:, None])
        kind = 1 + (len(PADS) if self.config.uses_tactile else 0)
        for module, key in ((self.past_agent, "past_agent"), (self.touch, "touch")):
            if module is not None:
                tokens.append((module(obs[key].flatten(1)) + self.type_embedding[kind])[:, None])
                kind += 1
        for name, cnn in self.cameras.items():
            tokens.append(cnn(obs[name]))
        memory = self.transformer_encoder(torch.cat(tokens, 1))
        queries = self.queries.expand(memory.shape[0], -1, -1)
        return self.head(self.transformer_decoder(queries, memory))


def past_agent_input(past: torch.Tensor, now: torch.Tensor, norm: Normalization) -> torch.Tensor:
    """The network's ``past_agent``: past agent_pos (B, H, 8), oldest first, relative to the present one
    (B, 8) and divided by agent_pos's std, so where the gripper was and how it moved, not where the scene is."""
    return (past - now[:, None]) / norm.agent_std


def touch_input(touch: torch.Tensor) -> torch.Tensor:
    """The network's ``touch``: (B, H + 1, 2, 4) ``TOUCH_SIGNALS`` (oldest first, the present last), each
    divided by its ``TOUCH_SCALE``."""
    return touch / torch.tensor(TOUCH_SCALE, dtype=touch.dtype)


def masked_l1(pred: torch.Tensor, target: torch.Tensor, is_pad: torch.Tensor) -> torch.Tensor:
    """Mean L1 over the actions that exist: (B, C, 8) against (B, C, 8), ``is_pad`` (B, C) True past the
    episode's end (those rows never count, whatever the padding put there)."""
    keep = (~is_pad).unsqueeze(-1).to(pred.dtype)
    return ((pred - target).abs() * keep).sum() / (keep.sum() * pred.shape[-1]).clamp_min(1.0)


# ---------------------------------------------------------------------------------------------- rollout

class TemporalEnsembler:
    """ACT's temporal ensembling: every step adds a chunk (C, D) predicted for steps t .. t + C - 1; the
    action for step t is the average of every prediction made for t, weighted exp(-k i) with i = 0 the
    oldest prediction (a negative k weights the newest most)."""

    def __init__(self, chunk: int, k: float) -> None:
        self.chunk, self.k = chunk, k
        self._chunks: deque[np.ndarray] = deque(maxlen=chunk)  # newest last; chunk j made j steps ago

    def reset(self) -> None:
        self._chunks.clear()

    def __call__(self, chunk: np.ndarray) -> np.ndarray:
        self._chunks.append(np.asarray(chunk, np.float64))
        n = len(self._chunks)
        # the chunk made (n - 1 - j) steps ago predicts this step at its row (n - 1 - j); j = 0 is the oldest
        rows = np.stack([c[n - 1 - j] for j, c in enumerate(self._chunks)])
        weights = np.exp(-self.k * np.arange(n))
        return (weights[:, None] * rows).sum(0) / weights.sum()


class ChunkPolicy:
    """What ``univtac-data evaluate`` calls: ``reset()``, ``act(obs) -> (8,)`` absolute action."""

    def __init__(self, net: ChunkPolicyNet, norm: Normalization, ensemble_k: float | None = None) -> None:
        self.net = net.eval()
        self.norm = norm
        self.config = net.config
        k = self.config.ensemble_k if ensemble_k is None else ensemble_k
        self.ensembler = TemporalEnsembler(self.config.chunk, k)
        # the previous steps' agent_pos (8,) and touch signals (2, 4), oldest first; before the rollout's
        # first step the first observation stands in for them (as the episode's first frame does in training)
        self._past: deque[tuple[np.ndarray, np.ndarray | None]] = deque(maxlen=max(self.config.history, 1))

    def reset(self) -> None:
        self.ensembler.reset()
        self._past.clear()

    def observation(self, obs: dict[str, Any],
                    now: tuple[np.ndarray, np.ndarray | None] | None = None) -> dict[str, torch.Tensor]:
        """An environment observation -> the network's inputs (batch of one), prepared as in training.
        ``now``: this observation's ``_now`` if the caller has it already."""
        cfg = self.config
        agent = torch.as_tensor(np.asarray(obs["agent_pos"], np.float32))[None]
        out = {"agent_pos": (agent - self.norm.agent_mean) / self.norm.agent_std}
        pixels = obs["pixels"]
        for name in cfg.cameras:
            if name not in pixels:
                raise KeyError(f"the policy was trained on the {name} camera; evaluate with cameras on")
            out[name] = resize_uint8(hwc_to_chw(pixels[name]), cfg.camera_hw).float() / 255.0
        if cfg.uses_tactile:
            for pad in PADS:
                out[f"tactile_{pad}"] = resize_uint8(hwc_to_chw(pixels[f"tactile_{pad}"]), cfg.tactile_hw).float() / 255.0
        if cfg.history:
            now = self._now(obs) if now is None else now
            past = list(self._past)
            past = [past[0] if past else now] * (cfg.history - len(past)) + past
            agents = torch.from_numpy(np.stack([a for a, _ in past]))[None]
            out["past_agent"] = past_agent_input(agents, agent[0][None], self.norm)
            if cfg.reads_touch:
                touches = np.stack([t for _, t in [*past, now]])  # type: ignore[misc]
                out["touch"] = touch_input(torch.from_numpy(touches)[None])
        return out

    def _now(self, obs: dict[str, Any]) -> tuple[np.ndarray, np.ndarray | None]:
        """This step's agent_pos and (if the network reads them) touch signals, as ``_past`` keeps them."""
        touch = touch_signals(obs) if self.config.reads_touch else None
        return np.asarray(obs["agent_pos"], np.float32), touch

    @torch.no_grad()
    def predict_chunk(self, obs: dict[str, Any],
                      now: tuple[np.ndarray, np.ndarray | None] | None = None) -> np.ndarray:
        """(C, 8) absolute actions (denormalised) for this step and the next C - 1."""
        pred = self.net(self.observation(obs, now))[0]
        chunk = (pred * self.norm.action_std + self.norm.action_mean).numpy()
        return absolute_chunk(chunk, np.asarray(obs["agent_pos"], np.float32), self.config)

    def act(self, obs: dict[str, Any]) -> np.ndarray:
        now = self._now(obs) if self.config.history else None  # read once: the input now, the past next step
        action = self.ensembler(self.predict_chunk(obs, now))
        if now is not None:
            self._past.append(now)
        quat = action[3:7]
        action[3:7] = quat / max(float(np.linalg.norm(quat)), 1e-9)
        return action.astype(np.float32)


# ------------------------------------------------------------------------------------------- checkpoints

def save_checkpoint(path: str | os.PathLike[str], net: ChunkPolicyNet, norm: Normalization,
                    extra: dict[str, Any] | None = None) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".part")
    torch.save({"config": net.config.to_dict(), "state_dict": net.state_dict(), "normalization": norm.to_dict(),
                "extra": extra or {}}, tmp)
    os.replace(tmp, path)


def load_checkpoint(path: str | os.PathLike[str]) -> tuple[ChunkPolicyNet, Normalization, dict[str, Any]]:
    data = torch.load(path, weights_only=False, map_location="cpu")
    net = ChunkPolicyNet(PolicyConfig.from_dict(data["config"]))
    net.load_state_dict(data["state_dict"])
    return net.eval(), Normalization.from_dict(data["normalization"]), data.get("extra", {})


def load_policy(path: str | os.PathLike[str], ensemble_k: float | None = None) -> ChunkPolicy:
    net, norm, _ = load_checkpoint(path)
    return ChunkPolicy(net, norm, ensemble_k)


def from_env() -> ChunkPolicy:
    """Factory for ``--policy act_policy:from_env``: the checkpoint at ``$UNIVTAC_POLICY_CHECKPOINT``;
    ``$UNIVTAC_POLICY_ENSEMBLE_K`` overrides the ensembling weight k (a negative k weights the newest
    prediction most: -10 is in effect the newest chunk's action alone, the most reactive rollout)."""
    path = os.environ.get(CHECKPOINT_ENV)
    if not path:
        raise RuntimeError(f"set {CHECKPOINT_ENV} to a checkpoint written by examples/train_policy.py")
    torch.set_num_threads(int(os.environ.get("UNIVTAC_POLICY_THREADS", "1")))
    k = os.environ.get(ENSEMBLE_K_ENV)
    return load_policy(path, float(k) if k else None)


def parameter_count(net: nn.Module, trainable: bool = True) -> int:
    return sum(p.numel() for p in net.parameters() if p.requires_grad or not trainable)


__all__ = ["CHECKPOINT_ENV", "TARGET_FRAMES", "VARIANTS", "ChunkPolicy", "ChunkPolicyNet", "Normalization", "PolicyConfig", "STD_FLOOR",
           "TOUCH_SCALE", "TOUCH_SIGNALS", "TemporalEnsembler", "absolute_chunk", "chunk_targets", "from_env",
           "past_agent_input", "touch_input", "touch_signals", "quat_mul", "load_checkpoint", "load_policy", "masked_l1", "resize_uint8",
           "save_checkpoint"]
