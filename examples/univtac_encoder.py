"""A reference UniVTAC encoder in plain torch (no torchvision): ResNet-18 backbone and five decoders.

From the paper's encoder section: a shared ResNet-18 maps a marked tactile image to a latent vector;
transposed-convolution decoders reconstruct I_marked and I_pure (RGB) and the depth map D (one channel);
a small MLP predicts the N marker positions M, another the 7-d object pose p. All decoders are used in
training only; downstream policies keep ``encode``. Loss (all MSE)::

    L_shape   = MSE(I_marked^, I_marked) + MSE(I_pure^, I_pure)
    L_contact = MSE(D^, D) + MSE(M^, M)
    L_pose    = MSE(p^, p)
    L_total   = 1.0 L_shape + 0.5 L_contact + 0.5 L_pose

Targets are the ``TactileFrameDataset`` samples: images (3, H, W) in [0, 1], depth (1, H, W) mm, markers
(N, 2) in [-1, 1], pose (7,) mm + unit quaternion with w >= 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn
from torch.nn import functional as F

LATENT_DIM = 512


class BasicBlock(nn.Module):
    """ResNet's two 3x3 convolutions with a skip connection (projected when the shape changes)."""

    def __init__(self, c_in: int, c_out: int, stride: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_out, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(c_out)
        self.conv2 = nn.Conv2d(c_out, c_out, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(c_out)
        self.skip: nn.Module = nn.Identity()
        if stride != 1 or c_in != c_out:
            self.skip = nn.Sequential(nn.Conv2d(c_in, c_out, 1, stride, bias=False), nn.BatchNorm2d(c_out))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = F.relu(self.bn1(self.conv1(x)))
        return F.relu(self.bn2(self.conv2(out)) + self.skip(x))


class ResNet18(nn.Module):
    """ResNet-18 (He et al. 2016; torchvision's layout): (B, 3, H, W) -> (B, 512) after global pooling."""

    def __init__(self) -> None:
        super().__init__()
        self.stem = nn.Sequential(nn.Conv2d(3, 64, 7, 2, 3, bias=False), nn.BatchNorm2d(64), nn.ReLU(inplace=True),
                                  nn.MaxPool2d(3, 2, 1))
        layers: list[nn.Module] = []
        c_in = 64
        for c_out, stride in ((64, 1), (128, 2), (256, 2), (512, 2)):
            layers += [BasicBlock(c_in, c_out, stride), BasicBlock(c_out, c_out, 1)]
            c_in = c_out
        self.layers = nn.Sequential(*layers)
        for module in self.modules():
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, mode="fan_out", nonlinearity="relu")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.flatten(F.adaptive_avg_pool2d(self.layers(self.stem(x)), 1), 1)


class ImageDecoder(nn.Module):
    """Latent (B, 512) -> (B, C, H, W): a linear seed at 1/32 resolution and five stride-2 transposed
    convolutions, cropped to (H, W). ``sigmoid`` bounds RGB outputs to [0, 1]."""

    def __init__(self, channels: int, height: int, width: int, sigmoid: bool) -> None:
        super().__init__()
        self.height, self.width, self.sigmoid = height, width, sigmoid
        self.seed_hw = (math.ceil(height / 32), math.ceil(width / 32))
        self.seed = nn.Linear(LATENT_DIM, 256 * self.seed_hw[0] * self.seed_hw[1])
        ups: list[nn.Module] = []
        c = 256
        for _ in range(5):
            ups += [nn.ConvTranspose2d(c, c // 2, 4, 2, 1), nn.BatchNorm2d(c // 2), nn.ReLU(inplace=True)]
            c //= 2
        self.up = nn.Sequential(*ups, nn.Conv2d(c, channels, 3, 1, 1))

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        x = self.up(self.seed(z).view(-1, 256, *self.seed_hw))[..., : self.height, : self.width]
        return torch.sigmoid(x) if self.sigmoid else x


def mlp(out_dim: int, hidden: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(LATENT_DIM, hidden), nn.ReLU(inplace=True), nn.Linear(hidden, out_dim))


@dataclass(frozen=True)
class LossWeights:
    """The paper's balancing weights."""

    shape: float = 1.0    # lambda_s, on I_marked and I_pure reconstruction
    contact: float = 0.5  # lambda_c, on depth D and markers M
    pose: float = 0.5     # lambda_p, on object pose p


class UniVTACEncoder(nn.Module):
    """ResNet-18 encoder plus the five training decoders, for images of ``height x width`` and
    ``n_markers`` markers (one sensor's marker count)."""

    def __init__(self, height: int, width: int, n_markers: int) -> None:
        super().__init__()
        self.n_markers = n_markers
        self.backbone = ResNet18()
        self.marked = ImageDecoder(3, height, width, sigmoid=True)
        self.pure = ImageDecoder(3, height, width, sigmoid=True)
        self.depth = ImageDecoder(1, height, width, sigmoid=False)
        self.markers = mlp(2 * n_markers, 256)
        self.pose = mlp(7, 128)

    def encode(self, marked_rgb: torch.Tensor) -> torch.Tensor:
        """(B, 3, H, W) float in [0, 1] -> (B, 512) features (what a policy keeps)."""
        return self.backbone(marked_rgb)

    def forward(self, marked_rgb: torch.Tensor) -> dict[str, torch.Tensor]:
        """Predictions keyed like the dataset's targets: marked_rgb, pure_rgb (B, 3, H, W), depth_mm
        (B, 1, H, W), markers (B, N, 2), object_pose (B, 7); plus ``features`` (B, 512)."""
        z = self.encode(marked_rgb)
        return {"features": z, "marked_rgb": self.marked(z), "pure_rgb": self.pure(z), "depth_mm": self.depth(z),
                "markers": self.markers(z).view(-1, self.n_markers, 2), "object_pose": self.pose(z)}


def univtac_loss(pred: dict[str, torch.Tensor], batch: dict[str, torch.Tensor],
                 weights: LossWeights = LossWeights()) -> dict[str, torch.Tensor]:
    """``total`` and the three terms ``shape``, ``contact``, ``pose`` (scalars), as in the paper."""
    shape = F.mse_loss(pred["marked_rgb"], batch["marked_rgb"]) + F.mse_loss(pred["pure_rgb"], batch["pure_rgb"])
    contact = F.mse_loss(pred["depth_mm"], batch["depth_mm"]) + F.mse_loss(pred["markers"], batch["markers"])
    pose = F.mse_loss(pred["object_pose"], batch["object_pose"])
    total = weights.shape * shape + weights.contact * contact + weights.pose * pose
    return {"total": total, "shape": shape, "contact": contact, "pose": pose}
