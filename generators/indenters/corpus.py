"""The indenter corpus: one episode = a gripper closing on an indenter to a random depth, then small random
rotations and moves that shear the gel, recorded at every frame.

Per episode (seeded; UniVTAC's numbers where it has them, in brackets):

* the indenter turned by a random angle about its axis; the gripper's contact point offset by up to
  +-2 mm across the pad and +-1 mm along the closing axis [grasp height 81 +- 5 mm];
* the closed-loop grasp to a depth threshold drawn from light touch to deep press:
  U(0.1, 0.8) x the sensor's safe limit [U(0, 0.3) mm];
* then, until the frame budget is spent, a random sequence of: twists about the closing axis of
  +-U(2, 8) deg in sub-steps of <= 0.2 rad [+-U(60, 70) deg, which slides the gel over the indenter; our
  twists stay mostly in stick so the markers show shear, with slip where friction gives], tilts of
  +-U(1, 3) deg about the pad axes, moves of U(0.2, 0.8) mm across the pad, and short holds; moves and
  twists are kept within +-1.5 mm and +-12 deg of the grasp pose.

The grip regulator keeps each pad at the threshold depth throughout, so depth never drifts past the safe
limit while the gripper moves.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import asdict, dataclass
from typing import Literal

import mujoco
import numpy as np

from univtac_data.episode import Episode
from univtac_data.generators.scene.gripper import PADS
from univtac_data.generators.indenters.scene import (
    BASE_CENTRE_M,
    BASE_HALF_THICKNESS_M,
    OBJECT_NAME,
    PAD_SIDE,
    SceneConfig,
    indenter_geom_names,
    indenter_scene_xml,
)
from univtac_data.generators.indenters.shapes import TIP_HEIGHT_M, get_indenter
from univtac_data.generators.scene.primitives import PRIMITIVE_NAMES, GraspParams, grasp, hold, move, rotate
from univtac_data.generators.scene.recording import build_episode
from univtac_data.generators.scene.sim import FrameBudgetReached, GripperSim, SimConfig
from univtac_data.generators.tactile import GelModel
from univtac_data.schema.models import GeneratorInfo
from univtac_data.schema.sensors import get_sensor
from univtac_data.version import __version__

GENERATOR_NAME = "univtac_data.generators.indenters.corpus"


@dataclass(frozen=True)
class IndenterEpisodeSpec:
    """Everything that determines one indenter episode (same spec, same arrays)."""

    sensor: str
    shape: str
    index: int  # episode number within (sensor, shape)
    base_seed: int = 0
    frames: int = 60
    contact_method: Literal["geometric", "elastic"] = "geometric"
    gel: GelModel = "half_space"  # elastic contact only
    record_rate_hz: float = 60.0
    timestep_s: float = 0.001

    @property
    def episode_id(self) -> str:
        return f"{self.sensor}-{self.shape}-{self.index:04d}"

    @property
    def seed(self) -> int:
        """A 63-bit seed from the base seed and the episode's identity (independent of run order)."""
        text = f"{self.base_seed}:{self.sensor}:{self.shape}:{self.index}".encode()
        return int.from_bytes(hashlib.sha256(text).digest()[:8], "little") >> 1


def corpus_specs(sensors: list[str], shapes: list[str], episodes_per_shape: int, **kwargs: object) \
        -> list[IndenterEpisodeSpec]:
    """The episodes of a corpus, in a fixed order."""
    for shape in shapes:
        get_indenter(shape)
    return [IndenterEpisodeSpec(sensor, shape, k, **kwargs)  # type: ignore[arg-type]
            for sensor in sensors for shape in shapes for k in range(episodes_per_shape)]


def _bounded(rng: np.random.Generator, current: float, low: float, high: float, limit: float) -> float:
    """A random step of magnitude U(low, high) whose sign keeps ``current + step`` within +-limit."""
    size = rng.uniform(low, high)
    sign = rng.choice((-1.0, 1.0))
    if abs(current + sign * size) > limit:
        sign = -sign
    return sign * size


def run_indenter_episode(spec: IndenterEpisodeSpec) -> Episode:
    """Simulate and record one episode."""
    profile = get_sensor(spec.sensor)
    indenter = get_indenter(spec.shape)
    rng = np.random.default_rng(spec.seed)
    yaw = rng.uniform(0, 2 * math.pi)
    offset = np.array([rng.uniform(-0.001, 0.001), rng.uniform(-0.002, 0.002), rng.uniform(-0.002, 0.002)])
    threshold = float(rng.uniform(0.1, 0.8) * profile.safe_indentation_mm)
    margin = rng.uniform(0.0015, 0.003)
    scene = SceneConfig(timestep_s=spec.timestep_s)
    start = tuple(float(v) for v in np.asarray(BASE_CENTRE_M) + offset)
    model = mujoco.MjModel.from_xml_string(indenter_scene_xml(profile, indenter, yaw_rad=yaw, config=scene,
                                                              gripper_pos=start))  # type: ignore[arg-type]
    sim = GripperSim(model, profile, {p: indenter_geom_names(indenter, PAD_SIDE[p]) for p in PADS}, OBJECT_NAME,
                     PRIMITIVE_NAMES, SimConfig(record_rate_hz=spec.record_rate_hz,
                                                contact_method=spec.contact_method, gel=spec.gel,
                                                max_frames=spec.frames))
    span = 2 * (BASE_HALF_THICKNESS_M + TIP_HEIGHT_M)
    sim.set_opening(span + 2 * margin)
    for _ in range(50):  # settle the fingers at the start opening; recording starts after
        sim.tick()
    sim.start_recording()

    try:
        _script(sim, rng, threshold)
    except FrameBudgetReached:
        pass
    if not sim.finite():
        raise FloatingPointError(f"{spec.episode_id}: the simulation went non-finite at t = {sim.time_s:.3f} s")
    generator = GeneratorInfo(name=GENERATOR_NAME, version=__version__, settings={
        **asdict(spec), "seed": spec.seed, "yaw_rad": yaw, "offset_m": offset.tolist(), "threshold_mm": threshold,
    })
    return build_episode(sim.frames, sim.pixel_arrays(), episode_id=spec.episode_id, kind="indenter", name=spec.shape,
                         sensor=spec.sensor, seed=spec.seed, generator=generator, success=None,
                         rate_hz=spec.record_rate_hz, primitive_names=PRIMITIVE_NAMES,
                         reference_rgb=sim.reference_rgb())


# Sliding the gel has done so far in an episode, mm, past which the script only holds. Slip accumulates and
# cannot be undone, and one twist or move adds at most about 0.3 mm (a 4 deg twist at the broad dome's ~5 mm
# contact radius), so episodes stay well inside the validators' 1 mm slip-while-held limit.
SLIP_BUDGET_MM = 0.3


def _slip_so_far_mm(sim: GripperSim) -> float:
    return max((float(f.tactile[p].slip_mm) for f in sim.frames[-1:] for p in PADS), default=0.0)


def _script(sim: GripperSim, rng: np.random.Generator, threshold: float) -> None:
    """Grasp, then random twists, tilts, moves and holds until the frame budget ends it; only holds once the
    episode's slip reaches ``SLIP_BUDGET_MM``."""
    grasp(sim, GraspParams(threshold_mm=threshold))
    twist, tilt_y, tilt_z, shift_y, shift_z = 0.0, 0.0, 0.0, 0.0, 0.0
    while True:
        action = rng.choice(("twist", "tilt", "move", "move", "hold"))
        if _slip_so_far_mm(sim) >= SLIP_BUDGET_MM:
            action = "hold"
        if action == "twist":
            angle = _bounded(rng, twist, math.radians(1), math.radians(4), math.radians(6))
            twist += angle
            rotate(sim, (1, 0, 0), angle, speed_rad_s=0.6)
        elif action == "tilt":
            axis = rng.choice((1, 2))
            angle = _bounded(rng, tilt_y if axis == 1 else tilt_z, math.radians(1), math.radians(3), math.radians(4))
            if axis == 1:
                tilt_y += angle
            else:
                tilt_z += angle
            rotate(sim, (0, 1, 0) if axis == 1 else (0, 0, 1), angle, speed_rad_s=0.3)
        elif action == "move":
            dy = _bounded(rng, shift_y, 0.00005, 0.0003, 0.0005)
            dz = _bounded(rng, shift_z, 0.00005, 0.0003, 0.0005)
            shift_y, shift_z = shift_y + dy, shift_z + dz
            move(sim, (0.0, dy, dz), speed_m_s=0.005, frame="gripper")
        else:
            hold(sim, rng.uniform(0.03, 0.1))
        if not sim.finite():
            return
