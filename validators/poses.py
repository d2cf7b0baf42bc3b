"""Finite-difference kinematics of stored poses: (T, 7) arrays of x, y, z (m) and a quaternion w, x, y, z."""

from __future__ import annotations

import numpy as np


def quaternion_norm_error(quaternions: np.ndarray) -> np.ndarray:
    """(T,) | |q| - 1 | of (T, 4) quaternions, dimensionless."""
    return np.abs(np.linalg.norm(quaternions.astype(np.float64), axis=-1) - 1.0)


def rotation_angles_rad(pose: np.ndarray) -> np.ndarray:
    """(T-1,) rotation between consecutive frames, rad; q and -q are the same rotation."""
    q = pose[:, 3:7].astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
        dots = np.abs(np.sum(q[1:] * q[:-1], axis=1))
    return 2.0 * np.arccos(np.clip(dots, 0.0, 1.0))


def linear_speeds_m_s(pose: np.ndarray, intervals_s: np.ndarray) -> np.ndarray:
    """(T-1,) mean translation speed over each frame interval, m/s."""
    steps = np.linalg.norm(np.diff(pose[:, :3].astype(np.float64), axis=0), axis=1)
    return steps / intervals_s


def angular_speeds_rad_s(pose: np.ndarray, intervals_s: np.ndarray) -> np.ndarray:
    """(T-1,) mean rotation speed over each frame interval, rad/s."""
    return rotation_angles_rad(pose) / intervals_s
