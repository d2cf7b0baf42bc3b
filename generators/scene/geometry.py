"""Rigid-body pose arithmetic on 7-vectors (x, y, z in m; quaternion w, x, y, z), pure numpy."""

from __future__ import annotations

import math

import numpy as np


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of (4,) quaternions w, x, y, z."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw])


def quat_conj(q: np.ndarray) -> np.ndarray:
    return np.array([q[0], -q[1], -q[2], -q[3]])


def quat_from_axis_angle(axis: np.ndarray | tuple[float, float, float], angle_rad: float) -> np.ndarray:
    axis = np.asarray(axis, float)
    axis = axis / np.linalg.norm(axis)
    return np.array([math.cos(angle_rad / 2), *(axis * math.sin(angle_rad / 2))])


def quat_to_mat(q: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix of a unit quaternion."""
    w, x, y, z = np.asarray(q, float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def mat_to_quat(m: np.ndarray) -> np.ndarray:
    """Unit quaternion (w >= 0) of a (3, 3) rotation matrix."""
    m = np.asarray(m, float)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    out = np.array(q) / np.linalg.norm(q)
    return out if out[0] >= 0 else -out


def pose_from(pos: np.ndarray, mat: np.ndarray) -> np.ndarray:
    """(7,) pose from a position (3,) and a rotation matrix (3, 3)."""
    return np.concatenate([np.asarray(pos, float), mat_to_quat(mat)])


def relative_pose(parent_pos: np.ndarray, parent_mat: np.ndarray, child_pos: np.ndarray,
                  child_mat: np.ndarray) -> np.ndarray:
    """(7,) pose of the child frame expressed in the parent frame (both given in a common frame)."""
    rel_pos = parent_mat.T @ (np.asarray(child_pos) - np.asarray(parent_pos))
    return pose_from(rel_pos, parent_mat.T @ child_mat)


def slerp(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
    """Unit quaternion a fraction ``t`` (0..1) of the way from ``a`` to ``b`` along the shorter arc."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    dot = float(np.dot(a, b))
    if dot < 0:
        b, dot = -b, -dot
    if dot > 0.9995:
        q = a + t * (b - a)
        return q / np.linalg.norm(q)
    theta = math.acos(min(1.0, dot))
    return (math.sin((1 - t) * theta) * a + math.sin(t * theta) * b) / math.sin(theta)
