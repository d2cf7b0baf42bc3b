"""The pieces of the encoder pretraining recipe (``examples/pretrain_encoder.py``), in plain torch.

* ``rotational_symmetry``: how many turns about its axis map an indenter onto itself, measured on the
  indenter definitions (``generators/indenters/shapes.py``), so the pose target drops what a shape makes
  unobservable: a continuous symmetry (sphere, cone, flat punch, dome) has no yaw at all, an order-k
  symmetry (hexagon 6, cross 4, ...) knows yaw only modulo 360/k deg.
* ``indenter_in_pad``: the pose of the pressed indenter (not the base plate the dataset's ``object_pose``
  holds) in the gel-pad-centre frame: position in mm and yaw about the pad normal in rad.
* ``TactileEncoder``: a small CNN (4 stages, 16-128 channels, global average pooling to 128 features, or
  average and maximum side by side to 256 with ``pool="avgmax"``, the recipe's choice) with
  the paper's three pathways as heads: shape (I_pure reconstruction, weighted toward the contact region, and
  an episode-consistency term), contact (depth map D weighted toward the contact, marker positions M, peak
  depth) and pose (symmetry-aware). ``space_to_depth=2`` feeds a 96 x 128 image as 2 x 2 pixel blocks at
  about the cost of 48 x 64, and ``target_height``/``target_width`` keep the decoder's targets small.
* ``augment``: what suits tactile images: a gain and offset per colour channel, pixel noise, and small
  shifts and turns by any angle (only for the second, consistency view, whose targets are not regressed);
  no flips, which would turn a chiral shape (pacman, star) into another image without changing its label.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from functools import lru_cache

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

CONTINUOUS = 0  # rotational symmetry order of a shape that any turn maps onto itself
POOLS = ("avg", "avgmax")


@lru_cache(maxsize=None)
def rotational_symmetry(shape: str, max_order: int = 12, tolerance_mm: float = 0.3) -> int:
    """The largest k <= ``max_order`` such that turning the indenter by 360/k deg about its axis maps its
    surface onto itself within ``tolerance_mm``; ``CONTINUOUS`` (0) when turns by arbitrary angles do
    (then yaw is unobservable). Measured on points sampled from the indenter's parts (deterministic)."""
    import trimesh

    from univtac_data.generators.indenters.shapes import get_indenter, indenter_mesh

    mesh = indenter_mesh(get_indenter(shape))
    dense, _ = trimesh.sample.sample_surface(mesh, 20000, seed=0)
    probe, _ = trimesh.sample.sample_surface(mesh, 1000, seed=1)
    dense_t = torch.as_tensor(dense * 1000.0, dtype=torch.float32)
    probe_t = torch.as_tensor(probe * 1000.0, dtype=torch.float32)

    def maps_onto_itself(angle: float) -> bool:
        c, s = math.cos(angle), math.sin(angle)
        rot = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        turned = probe_t @ rot.T
        nearest = torch.cdist(turned, dense_t).min(1).values
        return float(torch.quantile(nearest, 0.99)) < tolerance_mm

    if all(maps_onto_itself(a) for a in (0.37, 1.13, 2.71)):  # angles no order up to 12 contains
        return CONTINUOUS
    for k in range(max_order, 1, -1):
        if maps_onto_itself(2 * math.pi / k):
            return k
    return 1


def quat_to_mat(q: np.ndarray) -> np.ndarray:
    """(..., 4) w, x, y, z -> (..., 3, 3)."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def indenter_in_pad(object_pose: np.ndarray, pad: str, yaw_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Position (T, 3) mm and yaw (T,) rad of the indenter a pad presses, in that pad's gel-pad-centre frame.

    ``object_pose`` (T, 7) is the base plate's pose in the pad frame (mm, quaternion w, x, y, z), as the
    dataset stores it; the indenter sits on the plate's +x face (pressed by the right pad) or -x face (left
    pad), its own z along the face normal, turned by ``yaw_rad`` about it (``generators/indenters/scene.py``).
    Position is the indenter's mounting-face centre; yaw is the angle of the indenter's x axis in the pad's
    tangent plane (the pad axes other than the one the indenter's z follows).
    """
    normal = 1.0 if pad == "right" else -1.0
    half_thickness_mm = 5.0  # BASE_HALF_THICKNESS_M of the indenter scene, in mm
    face = _axis_angle_mat(np.array([0.0, 1.0, 0.0]), normal * math.pi / 2)
    turn = face @ _axis_angle_mat(np.array([0.0, 0.0, 1.0]), yaw_rad)
    r_obj = quat_to_mat(np.asarray(object_pose[:, 3:], np.float64))
    pos = np.asarray(object_pose[:, :3], np.float64) + r_obj @ np.array([normal * half_thickness_mm, 0.0, 0.0])
    r_ind = r_obj @ turn
    axis = int(np.argmax(np.abs(r_ind[:, :, 2]).mean(0)))  # the pad axis the indenter's z follows
    u, v = [a for a in range(3) if a != axis]
    yaw = np.arctan2(r_ind[:, v, 0], r_ind[:, u, 0])
    return pos, yaw


def _axis_angle_mat(axis: np.ndarray, angle: float) -> np.ndarray:
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


def yaw_target(yaw_rad: torch.Tensor, order: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(cos k yaw, sin k yaw) (B, 2) and a mask (B,) that is False where the shape is round (k = 0): the
    target is the same for every yaw the shape cannot tell apart."""
    k = order.to(yaw_rad.dtype)
    target = torch.stack([torch.cos(k * yaw_rad), torch.sin(k * yaw_rad)], 1)
    return target, order > 0


def yaw_error_deg(pred: torch.Tensor, yaw_rad: torch.Tensor, order: torch.Tensor) -> torch.Tensor:
    """Symmetry-aware yaw error (B,) deg for predicted (cos k yaw, sin k yaw): the smallest turn between the
    predicted and the true yaw modulo 360/k deg; NaN where the shape is round."""
    k = order.clamp_min(1).to(yaw_rad.dtype)
    diff = torch.atan2(pred[:, 1], pred[:, 0]) - k * yaw_rad
    diff = torch.atan2(torch.sin(diff), torch.cos(diff)).abs() / k
    return torch.where(order > 0, torch.rad2deg(diff), torch.full_like(diff, float("nan")))


@dataclass(frozen=True)
class EncoderConfig:
    """Architecture of ``TactileEncoder``: input ``height x width``, ``n_markers`` of the sensor, channel
    widths of the stages (each halves the image; the last width is the feature size per pooling), and the
    size ``target_height x target_width`` at which the decoder reconstructs I_pure and D (0: the input's).

    A larger input with one more stage costs little (the extra stage runs on few channels) and keeps the
    imprint's fine curvature, while the reconstruction targets can stay small: what the decoder must
    rebuild is the shape's outline, not the pixels."""

    height: int = 48
    width: int = 64
    n_markers: int = 63
    widths: tuple[int, ...] = (16, 32, 64, 128)
    projection_dim: int = 64
    decoder_width: int = 64
    pool: str = "avg"  # "avg": global average of the last map; "avgmax": average and maximum side by side
    target_height: int = 0
    target_width: int = 0
    space_to_depth: int = 1  # the input's f x f pixel blocks become 3 f^2 channels before the first stage

    def __post_init__(self) -> None:
        if self.pool not in POOLS:
            raise ValueError(f"pool {self.pool!r}: one of {POOLS}")
        if (self.target_height > 0) != (self.target_width > 0) or self.target_height < 0 or self.target_width < 0:
            raise ValueError(f"target size {self.target_height} x {self.target_width}: both positive, or both 0")
        f = self.space_to_depth
        if f < 1 or self.height % f or self.width % f:
            raise ValueError(f"space_to_depth {f}: a positive divisor of the input size {self.height} x {self.width}")

    @property
    def target_hw(self) -> tuple[int, int]:
        """Height and width of the reconstructed I_pure and D."""
        if self.target_height:
            return self.target_height, self.target_width
        return self.height, self.width

    @property
    def feature_dim(self) -> int:
        """Length of the feature vector ``encode`` returns."""
        return self.widths[-1] * (2 if self.pool == "avgmax" else 1)

    def to_dict(self) -> dict[str, object]:
        return {**asdict(self), "widths": list(self.widths)}


def conv_bn(c_in: int, c_out: int, stride: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, 3, stride, 1, bias=False), nn.BatchNorm2d(c_out),
                         nn.ReLU(inplace=True))


class TactileEncoder(nn.Module):
    """A marked tactile image (B, 3, H, W) in [0, 1] -> features (B, widths[-1]); the heads are used in
    training only. Inputs are normalised by the training set's per-channel mean and std (buffers, saved
    with the checkpoint)."""

    def __init__(self, config: EncoderConfig) -> None:
        super().__init__()
        self.config = config
        stages: list[nn.Module] = []
        c_in = 3 * config.space_to_depth ** 2
        for c in config.widths:
            stages += [conv_bn(c_in, c, 2), conv_bn(c, c, 1)]
            c_in = c
        self.backbone = nn.Sequential(*stages)
        feat = config.feature_dim
        self.register_buffer("mean", torch.full((1, 3, 1, 1), 0.5))
        self.register_buffer("std", torch.full((1, 3, 1, 1), 0.25))
        # the decoder starts from the feature vector (not the feature map), so what it reconstructs must be
        # in the features a probe reads
        target_h, target_w = config.target_hw
        self.seed_hw = (math.ceil(target_h / 16), math.ceil(target_w / 16))
        c = config.decoder_width
        self.seed = nn.Linear(feat, c * self.seed_hw[0] * self.seed_hw[1])
        ups: list[nn.Module] = []
        for _ in range(4):
            ups += [nn.ConvTranspose2d(c, c // 2, 4, 2, 1), nn.BatchNorm2d(c // 2), nn.ReLU(inplace=True)]
            c //= 2
        self.decoder = nn.Sequential(*ups, nn.Conv2d(c, 4, 3, 1, 1))  # I_pure (3) and D (1)
        self.contact_head = nn.Sequential(nn.Linear(feat, 256), nn.ReLU(inplace=True),
                                          nn.Linear(256, 2 * config.n_markers + 1))  # M and peak depth
        self.pose_head = nn.Sequential(nn.Linear(feat, 128), nn.ReLU(inplace=True), nn.Linear(128, 5))
        self.projection = nn.Sequential(nn.Linear(feat, feat), nn.ReLU(inplace=True),
                                        nn.Linear(feat, config.projection_dim))

    def encode(self, marked_rgb: torch.Tensor) -> torch.Tensor:
        """(B, 3, H, W) in [0, 1] -> (B, F) features (what a probe or a policy keeps)."""
        x = (marked_rgb - self.mean) / self.std
        if self.config.space_to_depth > 1:
            # lossless: each f x f block of pixels becomes channels, so a 2x larger image keeps its fine
            # detail (the imprint's curvature) at the cost of a 2x smaller one
            x = F.pixel_unshuffle(x, self.config.space_to_depth)
        fmap = self.backbone(x)
        avg = F.adaptive_avg_pool2d(fmap, 1).flatten(1)
        if self.config.pool == "avg":
            return avg
        # the maximum keeps where a local pattern (a sharp edge, a corner) is strongest, which the average
        # of a small imprint dilutes over the whole pad
        return torch.cat([avg, F.adaptive_max_pool2d(fmap, 1).flatten(1)], 1)

    def forward(self, marked_rgb: torch.Tensor) -> dict[str, torch.Tensor]:
        z = self.encode(marked_rgb)
        h, w = self.config.target_hw
        image = self.decoder(self.seed(z).view(-1, self.config.decoder_width, *self.seed_hw))[..., :h, :w]
        contact = self.contact_head(z)
        pose = self.pose_head(z)
        return {"features": z, "pure_rgb": torch.sigmoid(image[:, :3]), "depth_mm": image[:, 3:],
                "markers": contact[:, :-1].view(-1, self.config.n_markers, 2), "peak_depth_mm": contact[:, -1],
                "position_mm": pose[:, :3], "yaw_cs": pose[:, 3:], "embedding": self.projection(z)}


@dataclass(frozen=True)
class RecipeWeights:
    """Balancing weights of the recipe's loss terms (chosen so each is of order 0.1-1 at the start)."""

    shape: float = 1.0        # contact-weighted I_pure reconstruction
    consistency: float = 1.0  # episode-consistency (supervised-contrastive on the episode id)
    contact: float = 1.0      # contact-weighted D, markers, peak depth
    pose: float = 0.5         # position (mm / 2) and symmetry-aware yaw
    contact_weight: float = 10.0  # extra weight of pixels in or near the contact region
    temperature: float = 0.2


def contact_weights(depth_mm: torch.Tensor, extra: float) -> torch.Tensor:
    """Per-pixel weights (B, 1, H, W), mean 1 per image: 1 + ``extra`` inside the contact region grown by
    two pixels (where the imprint's edge, the shape's outline, is), so a blurry blob that gets the
    background right no longer scores well."""
    near = F.max_pool2d((depth_mm > 0.005).float(), 5, 1, 2)
    weights = 1.0 + extra * near
    return weights / weights.mean((1, 2, 3), keepdim=True)


def episode_consistency(embedding: torch.Tensor, episode: torch.Tensor, temperature: float) -> torch.Tensor:
    """Supervised-contrastive loss (Khosla et al. 2020) with the episode id as the label: frames of one
    episode (one indenter at one yaw, pressed and sheared) pull together, frames of other episodes push
    apart. Uses no shape label."""
    z = F.normalize(embedding, dim=1)
    logits = z @ z.T / temperature
    eye = torch.eye(len(z), dtype=torch.bool, device=z.device)
    logits = logits.masked_fill(eye, float("-inf"))
    positive = (episode[:, None] == episode[None, :]) & ~eye
    log_prob = logits.log_softmax(1).masked_fill(~positive, 0.0)
    has_positive = positive.any(1)
    return -(log_prob.sum(1)[has_positive] / positive.sum(1)[has_positive]).mean()


def recipe_loss(pred: dict[str, torch.Tensor], batch: dict[str, torch.Tensor], view2_embedding: torch.Tensor,
                weights: RecipeWeights = RecipeWeights()) -> dict[str, torch.Tensor]:
    """``total`` and the terms ``shape``, ``consistency``, ``contact``, ``pose`` (scalars)."""
    w = contact_weights(batch["depth_mm"], weights.contact_weight)
    shape = (w * (pred["pure_rgb"] - batch["pure_rgb"]).abs()).mean() * 10.0
    embeddings = torch.cat([pred["embedding"], view2_embedding])
    consistency = episode_consistency(embeddings, batch["episode"].repeat(2), weights.temperature)
    depth = (w * (pred["depth_mm"] - batch["depth_mm"]).abs()).mean() * 10.0
    markers = F.mse_loss(pred["markers"], batch["markers"]) * 100.0
    peak = F.smooth_l1_loss(pred["peak_depth_mm"], batch["peak_depth_mm"], beta=0.1) * 10.0
    contact = depth + markers + peak
    position = F.smooth_l1_loss(pred["position_mm"] / 2.0, batch["position_mm"] / 2.0)
    yaw_cs, observable = yaw_target(batch["yaw_rad"], batch["order"])
    yaw = ((pred["yaw_cs"] - yaw_cs) ** 2).sum(1)
    yaw = (yaw * observable).sum() / observable.sum().clamp_min(1)
    pose = position + yaw
    total = (weights.shape * shape + weights.consistency * consistency + weights.contact * contact
             + weights.pose * pose)
    return {"total": total, "shape": shape, "consistency": consistency, "contact": contact, "pose": pose}


@dataclass(frozen=True)
class Augment:
    """Tactile-image augmentation: gain and offset per colour channel (illumination and camera drift), pixel
    noise, and shifts of up to ``shift_px`` (a slightly different gel placement). No flips (they would turn a
    chiral shape, pacman or star, into another image with the same label).

    ``rotate_deg``: the second, consistency view is also turned about the image centre by up to this many
    degrees either way (180: any turn). Why: an episode holds one indenter at one yaw, so without turns the
    cheapest way to tell episodes apart is the imprint's orientation, and a line from a cylinder's side and
    from a prism's edge at the same yaw end up as neighbours; turned positives make the contrastive embedding
    blind to yaw, so episodes of one shape at different yaws meet and the shape's profile is what is left
    to tell episodes apart. Only the consistency view turns: the pose targets of the first view stay exact."""

    gain: float = 0.1
    offset: float = 0.03
    noise: float = 0.01
    shift_px: int = 3
    rotate_deg: float = 0.0

    def photometric(self, images: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
        b = images.shape[0]
        gain = 1.0 + self.gain * (2 * torch.rand(b, 3, 1, 1, generator=gen) - 1)
        offset = self.offset * (2 * torch.rand(b, 3, 1, 1, generator=gen) - 1)
        noise = self.noise * torch.randn(images.shape, generator=gen)
        return (images * gain + offset + noise).clamp(0, 1)

    def shift(self, images: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
        """Each image moved by up to ``shift_px`` pixels in x and y (edges replicated)."""
        s = self.shift_px
        if s == 0:
            return images
        h, w = images.shape[-2:]
        padded = F.pad(images, (s, s, s, s), mode="replicate")
        dy = torch.randint(0, 2 * s + 1, (images.shape[0],), generator=gen)
        dx = torch.randint(0, 2 * s + 1, (images.shape[0],), generator=gen)
        return torch.stack([padded[i, :, dy[i]:dy[i] + h, dx[i]:dx[i] + w] for i in range(images.shape[0])])

    def rotate(self, images: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
        """Each image turned about its centre by a uniform angle in +-``rotate_deg`` (in pixel space, so a
        non-square image turns without shearing; what comes in from outside the frame repeats the border)."""
        if self.rotate_deg == 0:
            return images
        angle = torch.deg2rad(self.rotate_deg * (2 * torch.rand(images.shape[0], generator=gen) - 1))
        return rotate_images(images, angle)


def rotate_images(images: torch.Tensor, angle_rad: torch.Tensor) -> torch.Tensor:
    """(B, C, H, W) turned by ``angle_rad`` (B,) about the image centre, +x toward +y (clockwise as displayed
    with y down), bilinear, border repeated."""
    h, w = images.shape[-2:]
    c, s = torch.cos(angle_rad), torch.sin(angle_rad)
    # grid_sample's coordinates are normalised per axis; the aspect ratio makes a pixel-space turn
    theta = torch.stack([torch.stack([c, s * h / w, torch.zeros_like(c)], 1),
                         torch.stack([-s * w / h, c, torch.zeros_like(c)], 1)], 1)
    grid = F.affine_grid(theta.to(images.dtype), list(images.shape), align_corners=False)
    return F.grid_sample(images, grid, mode="bilinear", padding_mode="border", align_corners=False)
