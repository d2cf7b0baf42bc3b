"""The 14 indenters of the encoder-pretraining corpus, built procedurally (nothing is downloaded).

Each indenter is a union of convex parts in its own frame: the mounting face is the plane z = 0, the shape
protrudes toward +z, and every shape's highest point is at ``TIP_HEIGHT_M``. Convex parts are what MuJoCo
collides exactly (it replaces a non-convex mesh by its convex hull), so a non-convex shape such as a cross is
two boxes, not one mesh; the tactile gap field sees the same parts, so physics and images agree.

Seven shapes are convex (a single curvature class each: point, edge, flat and large-radius contact) and
seven are not (several patches, holes, textures); together they span the curvature and topology that
Kim et al.'s marker-embedded image generation and TacEx's test set use. Sizes fit inside the smallest
imaged area (Xense WS, 29.3 x 17.5 mm): every shape lies within a 15 x 15 mm footprint.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import trimesh

TIP_HEIGHT_M = 0.005  # how far every indenter protrudes from its mounting face, m
PartKind = Literal["sphere", "ellipsoid", "capsule", "box", "cylinder", "mesh"]


@dataclass(frozen=True)
class Part:
    """One convex piece, in the indenter frame (m). ``size`` follows MJCF: sphere (r,), ellipsoid (rx, ry, rz), capsule and
    cylinder (r, half-length along the part's z), box (half-x, half-y, half-z); ``vertices`` (V, 3) for a
    convex mesh. ``quat`` is w, x, y, z."""

    kind: PartKind
    pos: tuple[float, float, float]
    size: tuple[float, ...] = ()
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    vertices: np.ndarray | None = field(default=None, compare=False)


@dataclass(frozen=True)
class Indenter:
    name: str
    convex: bool
    description: str
    parts: tuple[Part, ...]


_X_AXIS = (math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0)  # rotates the part's z onto the x axis
_Y_AXIS = (math.cos(math.pi / 4), -math.sin(math.pi / 4), 0.0, 0.0)  # rotates the part's z onto the y axis


def _prism(polygon_xy: np.ndarray, height: float = TIP_HEIGHT_M, z0: float = 0.0) -> Part:
    """A convex polygon (K, 2) in m extruded from z0 to z0 + height."""
    bottom = np.column_stack([polygon_xy, np.full(len(polygon_xy), z0)])
    top = np.column_stack([polygon_xy, np.full(len(polygon_xy), z0 + height)])
    return Part("mesh", (0.0, 0.0, 0.0), vertices=np.vstack([bottom, top]))


def _circle(radius: float, n: int, start: float = 0.0, stop: float | None = None, centre: bool = False) -> np.ndarray:
    """``n`` points on a circle from ``start`` to ``stop`` rad (a full turn, without repeating, by default)."""
    full_turn = stop is None
    stop = start + 2 * math.pi if stop is None else stop
    angles = np.linspace(start, stop, n, endpoint=not full_turn)
    points = radius * np.column_stack([np.cos(angles), np.sin(angles)])
    return np.vstack([[0.0, 0.0], points]) if centre else points


def _convex() -> list[Indenter]:
    h = TIP_HEIGHT_M
    truncated_cone = np.vstack([
        np.column_stack([_circle(0.005, 32), np.zeros(32)]),
        np.column_stack([_circle(0.0008, 16), np.full(16, h)]),
    ])
    ridge = np.array([[-0.007, -0.004, 0], [-0.007, 0.004, 0], [0.007, -0.004, 0], [0.007, 0.004, 0],
                      [-0.007, -0.0003, h], [-0.007, 0.0003, h], [0.007, -0.0003, h], [0.007, 0.0003, h]])
    return [
        Indenter("sphere", True, "hemisphere, radius 5 mm: the Hertz point contact",
                 (Part("sphere", (0, 0, 0), (h,)),)),
        Indenter("cone", True, "truncated cone, base radius 5 mm, tip radius 0.8 mm: a sharp point contact",
                 (Part("mesh", (0, 0, 0), vertices=truncated_cone),)),
        Indenter("cylinder", True, "flat punch, radius 4 mm: uniform pressure with edge peaks",
                 (Part("cylinder", (0, 0, h / 2), (0.004, h / 2)),)),
        Indenter("cylinder_side", True, "cylinder of radius 3 mm lying along x: a line contact",
                 (Part("cylinder", (0, 0, h - 0.003), (0.003, 0.007), _X_AXIS),)),
        Indenter("prism", True, "triangular ridge, 8 mm wide, 14 mm long: a sharp edge contact",
                 (Part("mesh", (0, 0, 0), vertices=ridge),)),
        Indenter("hexagon", True, "hexagonal prism, circumradius 5 mm: a flat face with corners",
                 (_prism(_circle(0.005, 6)),)),
        Indenter("curved_surface", True, "flat ellipsoidal dome, 22 mm across, tip curvature radius 30 mm: "
                 "a broad, gentle contact", (Part("ellipsoid", (0, 0, 0.001), (0.011, 0.011, 0.004)),)),
    ]


def _non_convex() -> list[Indenter]:
    h = TIP_HEIGHT_M
    star: list[Part] = []
    outer, inner = 0.007, 0.0028
    for k in range(5):
        tip = 2 * math.pi * k / 5 + math.pi / 2
        left, right = tip - math.pi / 5, tip + math.pi / 5
        star.append(_prism(np.array([[inner * math.cos(left), inner * math.sin(left)],
                                     [outer * math.cos(tip), outer * math.sin(tip)],
                                     [inner * math.cos(right), inner * math.sin(right)]])))
    star.append(_prism(_circle(inner, 5, start=math.pi / 2 + math.pi / 5)))
    mouth = math.radians(60)
    pacman = [_prism(_circle(0.006, 24, mouth / 2 + s * (2 * math.pi - mouth) / 2,
                             mouth / 2 + (s + 1) * (2 * math.pi - mouth) / 2, centre=True)) for s in range(2)]
    dots = tuple(Part("capsule", (x, y, 0.0015), (0.002, 0.0015)) for x, y in
                 [(0, 0), (0.0045, 0.0045), (-0.0045, 0.0045), (0.0045, -0.0045), (-0.0045, -0.0045)])
    ring_radius, tube = 0.005, 0.0015
    ring: list[Part] = [Part("cylinder", (0, 0, 0.001), (ring_radius + tube, 0.001))]
    for k in range(12):
        angle = 2 * math.pi * k / 12
        half = math.sin(math.pi / 12) * ring_radius
        yaw = angle + math.pi / 2  # capsule along the tangent
        quat = _quat_from_z_to((math.cos(yaw), math.sin(yaw), 0.0))
        ring.append(Part("capsule", (ring_radius * math.cos(angle), ring_radius * math.sin(angle), h - tube),
                         (tube, half), quat))
    wave = tuple(Part("cylinder", (x, 0, h - 0.002), (0.002, 0.007), _Y_AXIS)
                 for x in (-0.0064, -0.0032, 0.0, 0.0032, 0.0064))
    lines = tuple(Part("box", (0, y, h / 2), (0.007, 0.00075, h / 2)) for y in (-0.004, 0.0, 0.004))
    return [
        Indenter("cross", False, "two 14 x 3 mm bars crossing: four arms and re-entrant corners",
                 (Part("box", (0, 0, h / 2), (0.007, 0.0015, h / 2)),
                  Part("box", (0, 0, h / 2), (0.0015, 0.007, h / 2)))),
        Indenter("star", False, "five-pointed star, outer radius 7 mm: sharp re-entrant corners", tuple(star)),
        Indenter("pacman", False, "disk of radius 6 mm with a 60 deg wedge cut out", tuple(pacman)),
        Indenter("dots", False, "five round-tipped pins of radius 2 mm: separate contact patches", dots),
        Indenter("torus", False, "ring of radius 5 mm (tube 1.5 mm) on a low disk: a contact with a hole",
                 tuple(ring)),
        Indenter("wave", False, "five overlapping cylinders: a corrugated surface, period 3.2 mm", wave),
        Indenter("parallel_lines", False, "three 1.5 mm bars, 4 mm apart: parallel line contacts", lines),
    ]


def _quat_from_z_to(direction: tuple[float, float, float]) -> tuple[float, float, float, float]:
    """Unit quaternion (w, x, y, z) rotating +z onto ``direction``."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, d)
    s, c = np.linalg.norm(axis), float(z @ d)
    if s < 1e-12:
        return (1.0, 0.0, 0.0, 0.0) if c > 0 else (0.0, 1.0, 0.0, 0.0)
    angle = math.atan2(s, c)
    axis /= s
    return (math.cos(angle / 2), *(float(a) * math.sin(angle / 2) for a in axis))  # type: ignore[return-value]


INDENTERS: dict[str, Indenter] = {i.name: i for i in (*_convex(), *_non_convex())}
INDENTER_NAMES: tuple[str, ...] = tuple(INDENTERS)


def get_indenter(name: str) -> Indenter:
    try:
        return INDENTERS[name]
    except KeyError:
        raise KeyError(f"unknown indenter {name!r}; known: {', '.join(INDENTER_NAMES)}") from None


def part_mesh(part: Part) -> trimesh.Trimesh:
    """A triangle mesh of one part in the indenter frame (for pictures and checks, not for MuJoCo)."""
    if part.kind == "mesh":
        assert part.vertices is not None
        mesh = trimesh.convex.convex_hull(part.vertices)
    elif part.kind == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=3, radius=part.size[0])
    elif part.kind == "ellipsoid":
        mesh = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
        mesh.apply_scale(part.size)
    elif part.kind == "capsule":
        mesh = trimesh.creation.capsule(height=2 * part.size[1], radius=part.size[0], count=[32, 32])
    elif part.kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=part.size[0], height=2 * part.size[1])
    else:
        mesh = trimesh.creation.box(extents=[2 * s for s in part.size])
    transform = trimesh.transformations.quaternion_matrix(part.quat)
    transform[:3, 3] = part.pos
    mesh.apply_transform(transform)
    return mesh


def indenter_mesh(indenter: Indenter) -> trimesh.Trimesh:
    """All parts of an indenter as one mesh in the indenter frame (parts overlap; not a boolean union)."""
    return trimesh.util.concatenate([part_mesh(p) for p in indenter.parts])
