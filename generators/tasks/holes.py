"""Holes for the insertion tasks, built from boxes: a bore is a ring of box walls, a plate a frame of boxes.

MuJoCo collides convex shapes only, so a round hole is a ring of ``n_walls`` boxes whose inner faces are
the sides of a regular polygon with the bore radius as its inscribed radius: a cylinder of the bore's
radius touches every face, and between faces (the polygon's corners) the bore is wider by
``radius (1 / cos(pi / n) - 1)`` (0.09 mm for a 10.25 mm bore of 24 walls). Walls are static geoms of a
body placed in the hole frame: origin at the centre of the entrance, +z the bore axis pointing out of the
material, x and y across it (all lengths m).

``radial_room_m`` and ``tube_in_solid_mm`` give the geometry the tests check poses against (no tunnelling).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from univtac_data.generators.scene.geometry import quat_from_axis_angle, quat_mul, quat_to_mat


@dataclass(frozen=True)
class HoleContact:
    """Contact of the tube with a hole's walls (MuJoCo solref as time constant and damping ratio, solimp,
    margin). Chosen by benchmarks/insertion_stability.py: 0.002 s (the stiffest MuJoCo allows at a 1 ms step,
    two steps) keeps the peak penetration under the 0.25 mm clearance (0.14 mm), at no cost in speed;
    MuJoCo's default (0.02 s, solimp 0.9-0.95) lets a pushed tube sink 0.75 mm into the walls."""

    timeconst_s: float = 0.002
    dampratio: float = 1.0
    solimp: tuple[float, float, float] = (0.95, 0.99, 0.001)
    margin_m: float = 0.0
    friction: float = 0.3  # glass or plastic on a smooth bore (MuJoCo takes the larger of the two geoms')

    def attrs(self) -> str:
        imp = " ".join(f"{v:g}" for v in self.solimp)
        return (f' solref="{self.timeconst_s:g} {self.dampratio:g}" solimp="{imp}" margin="{self.margin_m:g}"'
                f' friction="{self.friction:g} 0.005 0.0001"')


@dataclass(frozen=True)
class Bore:
    """A round bore of ``radius_m`` (the walls' inscribed radius), ``depth_m`` long, open at both ends."""

    radius_m: float
    depth_m: float
    n_walls: int = 24
    wall_thickness_m: float = 0.014  # radial: the ring's outer radius covers a plate's square opening
    chamfer_m: float = 0.0  # a 45 deg chamfer this wide (radially and axially) at the entrance
    rgba: str = "0.55 0.6 0.68 1"

    def walls_xml(self, prefix: str, top_z: list[float] | None = None, *, attrs: str = "") -> str:
        """MJCF geoms of the ring, in the hole frame; wall k spans z from -depth to ``top_z[k]`` (default 0).
        With a chamfer the ring is two rings (the bore below the chamfer, a wider one beside it) and a ring
        of boxes turned 45 deg whose inner faces are the chamfer."""
        out = []
        c = self.chamfer_m
        tops = top_z if top_z is not None else [0.0] * self.n_walls
        out += self._ring(prefix, "wall", self.radius_m, [-c if c > 0 else t for t in tops], attrs)
        if c > 0:
            out += self._ring(prefix, "rim", self.radius_m + c, [t for t in tops], attrs, bottom=-c)
            out += self._chamfer(prefix, attrs)
        return "\n      ".join(out)

    def _ring(self, prefix: str, part: str, inner_m: float, tops: list[float], attrs: str,
              bottom: float | None = None) -> list[str]:
        half_t = self.wall_thickness_m / 2
        # tangential half-width: neighbouring walls meet at the outer radius, so the ring has no gaps
        half_w = (self.radius_m + self.wall_thickness_m) * math.tan(math.pi / self.n_walls) + 1e-4
        low = -self.depth_m if bottom is None else bottom
        out = []
        for k in range(self.n_walls):
            a = 2 * math.pi * k / self.n_walls
            half_len = (tops[k] - low) / 2
            cz = tops[k] - half_len
            r = inner_m + half_t
            out.append(f'<geom name="{prefix}_{part}{k}" type="box" pos="{r * math.cos(a):.6f} {r * math.sin(a):.6f} '
                       f'{cz:.6f}" euler="0 0 {a:.6f}" size="{half_t:.6f} {half_w:.6f} {half_len:.6f}" '
                       f'rgba="{self.rgba}"{attrs}/>')
        return out

    def _chamfer(self, prefix: str, attrs: str) -> list[str]:
        """Boxes turned 45 deg about their tangent: each inner face runs from (radius, -c) to (radius + c, 0)
        (radial, axial); the box lies behind that face, inside the two rings' material."""
        c = self.chamfer_m
        half_t = 0.002
        half_w = (self.radius_m + 2 * c) * math.tan(math.pi / self.n_walls) + 1e-4
        half_s = c * math.sqrt(2) / 2
        out = []
        for k in range(self.n_walls):
            a = 2 * math.pi * k / self.n_walls
            # face centre (radius + c/2, -c/2); the box centre half a thickness behind it, along (1, -1)/sqrt 2
            rc = self.radius_m + c / 2 + half_t / math.sqrt(2)
            zc = -c / 2 - half_t / math.sqrt(2)
            quat = quat_mul(quat_from_axis_angle((0, 0, 1), a), quat_from_axis_angle((0, 1, 0), math.pi / 4))
            q = " ".join(f"{v:.9f}" for v in quat)
            out.append(f'<geom name="{prefix}_chamfer{k}" type="box" pos="{rc * math.cos(a):.6f} {rc * math.sin(a):.6f} '
                       f'{zc:.6f}" quat="{q}" size="{half_t:.6f} {half_w:.6f} {half_s:.6f}" rgba="{self.rgba}"{attrs}/>')
        return out

    def convex_walls(self, prefix: str, n_pieces: int, attrs: str = "") -> tuple[str, str]:
        """The bore below the chamfer as ``n_pieces`` convex mesh wedges (a convex decomposition of the ring:
        each piece a prism on a trapezoid whose inner side is a chord at the bore's radius), for the stability
        study; returns (asset MJCF, geom MJCF). The chamfer and the rim stay boxes."""
        half = math.pi / n_pieces
        r_in, r_out = self.radius_m / math.cos(half), self.radius_m + self.wall_thickness_m
        top, bottom = -self.chamfer_m, -self.depth_m
        corners = [(r_in * math.cos(-half), r_in * math.sin(-half)), (r_in * math.cos(half), r_in * math.sin(half)),
                   (r_out * math.cos(half), r_out * math.sin(half)), (r_out * math.cos(-half), r_out * math.sin(-half))]
        verts = " ".join(f"{x:.6f} {y:.6f} {z:.6f}" for z in (bottom, top) for x, y in corners)
        asset = f'<mesh name="{prefix}_wedge" vertex="{verts}"/>'
        geoms = [f'<geom name="{prefix}_piece{k}" type="mesh" mesh="{prefix}_wedge" euler="0 0 {2 * math.pi * k / n_pieces:.6f}" '
                 f'rgba="{self.rgba}"{attrs}/>' for k in range(n_pieces)]
        rest = []
        if self.chamfer_m > 0:
            rest = self._ring(prefix, "rim", self.radius_m + self.chamfer_m, [0.0] * self.n_walls, attrs,
                              bottom=-self.chamfer_m) + self._chamfer(prefix, attrs)
        return asset, "\n      ".join(geoms + rest)

    def radial_room_m(self, tube_radius_m: float) -> float:
        """How far a tube's axis may sit from the bore's axis inside the bore (the diametral clearance / 2)."""
        return self.radius_m - tube_radius_m


def square_plate_xml(prefix: str, half_outer_m: float, half_inner_m: float, thickness_m: float, rgba: str,
                     attrs: str = "") -> str:
    """Four boxes forming a square plate (top face at z = 0, hole frame) with a square opening of half-side
    ``half_inner_m`` (the bore ring fills the opening's corners)."""
    w = (half_outer_m - half_inner_m) / 2
    c = half_inner_m + w
    hz = thickness_m / 2
    parts = [(c, 0.0, w, half_outer_m), (-c, 0.0, w, half_outer_m), (0.0, c, half_inner_m, w), (0.0, -c, half_inner_m, w)]
    return "\n      ".join(
        f'<geom name="{prefix}_plate{k}" type="box" pos="{x:.6f} {y:.6f} {-hz:.6f}" size="{sx:.6f} {sy:.6f} {hz:.6f}" '
        f'rgba="{rgba}"{attrs}/>' for k, (x, y, sx, sy) in enumerate(parts))


def in_hole_frame(hole_pos: np.ndarray, hole_quat: np.ndarray, point_world: np.ndarray) -> np.ndarray:
    """(3,) a world point in the hole frame (m)."""
    return quat_to_mat(hole_quat).T @ (np.asarray(point_world, float) - np.asarray(hole_pos, float))


def tube_surface_points(tube_pose: np.ndarray, radius_m: float, half_length_m: float, n_around: int = 24,
                        n_along: int = 25) -> np.ndarray:
    """(n, 3) points on a tube's side and on the rims of its ends, world m."""
    mat = quat_to_mat(tube_pose[3:])
    a = np.linspace(0.0, 2 * math.pi, n_around, endpoint=False)
    ring = radius_m * (np.cos(a)[:, None] * mat[:, 0] + np.sin(a)[:, None] * mat[:, 1])
    s = np.linspace(-half_length_m, half_length_m, n_along)
    return (tube_pose[:3] + s[:, None, None] * mat[:, 2] + ring[None, :, :]).reshape(-1, 3)


def tube_in_solid_mm(tube_pose: np.ndarray, tube_radius_m: float, half_length_m: float, hole_pos: np.ndarray,
                     hole_quat: np.ndarray, bore: Bore, mouth_m: float | None = None) -> float:
    """How deep the tube's surface is inside the bore's walls, mm (0: nowhere; the tests' tunnelling check).

    Points of the tube's side and end rims that lie along the bore, below its mouth (``mouth_m`` below the
    entrance, default the chamfer: above it the walls recede or end) and above its far end, may be no farther
    from the bore's axis than its radius (the polygon's corners are a little wider). A tube that went through
    the rim or the surface beside the hole shows a depth of millimetres.
    """
    mouth = bore.chamfer_m if mouth_m is None else mouth_m
    mat = quat_to_mat(hole_quat)
    pts = (tube_surface_points(tube_pose, tube_radius_m, half_length_m) - np.asarray(hole_pos, float)) @ mat
    inside = (pts[:, 2] < -mouth) & (pts[:, 2] > -bore.depth_m)
    if not inside.any():
        return 0.0
    reach = np.hypot(pts[inside, 0], pts[inside, 1])
    return float(max(0.0, (reach - bore.radius_m).max()) * 1000.0)


__all__ = ["Bore", "HoleContact", "in_hole_frame", "square_plate_xml", "tube_in_solid_mm", "tube_surface_points"]
