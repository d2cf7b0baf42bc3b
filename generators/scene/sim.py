"""``GripperSim``: a MuJoCo scene with the tactile gripper, stepped under a controller, recorded at a fixed rate.

The class owns the MuJoCo model/data, the commanded set-points (end-effector pose, gel opening) and the
per-pad tactile state; primitives (``primitives.py``) drive it through ``tick``. Physics runs at the model's
timestep; the controller ticks every ``control_period_steps`` physics steps; after ``start_recording()`` a
frame is recorded every ``1 / record_rate_hz`` s, or, with ``record_rate_hz=None``, whenever the caller asks
(``record_frame()``: the task environments record once per policy step). Recording reads the state and never
changes it, so the physics is the same with or without recording, cameras or tactile images. Everything is
deterministic for a given model and command sequence.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal

import mujoco
import numpy as np

from univtac_data.generators.scene.cameras import CameraRig, CameraSpec
from univtac_data.generators.scene.frame_stack import PIXEL_FIELDS, FrameStack
from univtac_data.generators.scene.geometry import mat_to_quat, relative_pose
from univtac_data.generators.scene.gripper import FINGER_TRAVEL_M, PADS, finger_pos_to_opening, opening_to_finger_pos
from univtac_data.generators.scene.texture import CylinderGrooves, add_cylinder_grooves
from univtac_data.generators.scene.touch import TouchReading, read_touch
from univtac_data.generators.tactile import (
    ContactConfig,
    ContactState,
    GapFieldBuffer,
    GelModel,
    PadPose,
    PixelBuffers,
    TactileConfig,
    gap_field,
    pad_pose,
    render_reference,
    sensor_grid,
    simulate_frame,
)
from univtac_data.schema.sensors import SensorProfile

GAP_PROBE_MAX_MM = 10.0  # farthest pad-object distance the controllers need to know, mm
# Gap beyond this reads as "far" in the tactile gap field: the elastic contact solve and the shading only
# see the gel where the object is within a fraction of a millimetre, so farther geometry is not worth
# evaluating. The geometric contact reads the overlap alone (gap < 0), so for it the gap field stops at the
# gel surface: the same frames from the part of the object below it, on a window a fraction of the size.
TACTILE_GAP_CUTOFF_MM = {"elastic": 2.0, "geometric": 0.0}


class FrameBudgetReached(Exception):
    """Raised by ``GripperSim.tick`` once ``SimConfig.max_frames`` frames are recorded: scripts stop there."""


@dataclass(frozen=True)
class SimConfig:
    record_rate_hz: float | None = 60.0  # UniVTAC saves data at 60 Hz; None records nothing (physics only)
    control_period_steps: int = 2  # controller ticks every 2 physics steps (500 Hz at dt = 1 ms)
    contact_method: Literal["geometric", "elastic"] = "geometric"  # tactile contact model
    gel: GelModel = "half_space"  # elastic: the gel as a half-space or as a bonded layer (ContactConfig.gel)
    # Cell sizes in mm, turned into whole pixels per sensor (``cell_steps``) so that every sensor gets the same
    # physical resolution: the GF225's pixels are 0.05 mm, the others' 0.085 mm.
    # Stick/slip shear solve: 0.66 mm is a quarter of the marker pitch (8 px on a GelSight Mini); the solve
    # dominates a frame and costs about 3x more at half the cell.
    shear_cell_mm: float = 0.66
    # Elastic normal solve: 0.17 mm keeps Hertz force within 2 % and contact radius within 4.5 % (2 px on a
    # GelSight Mini, 3 px on a GF225; benchmarks/results/tactile_speed_vs_accuracy.json).
    solver_cell_mm: float = 0.17
    max_frames: int | None = None  # stop (FrameBudgetReached) once this many frames are recorded
    # Frames to allocate the recording buffers for when ``max_frames`` is not set (a task's step limit): the
    # buffers are reserved, not touched, so an episode that ends early costs nothing, where growing them by
    # doubling copied every frame recorded so far (a tenth of a frame without cameras).
    frame_capacity: int = 64
    # Elastic solver stop: relative change of the pressure. 1e-4 gives the same forces to four digits and
    # depth within the 1 um storage quantum as 1e-6, in two thirds of the time (docs/tactile.md).
    contact_tol: float = 1e-4

    def __post_init__(self) -> None:
        # a NaN or infinite rate never reaches the next recording time: the episode would run forever
        if self.record_rate_hz is not None and not (math.isfinite(self.record_rate_hz) and self.record_rate_hz > 0):
            raise ValueError(f"record_rate_hz must be a positive number of Hz (got {self.record_rate_hz})")


def cell_steps(profile: SensorProfile, config: SimConfig) -> tuple[int, int]:
    """(elastic solver step, shear step) in image pixels for ``profile``: the configured cell sizes (mm)
    rounded to whole pixels, the shear step a whole multiple of the solver step (the shear grid is built
    by merging solver cells)."""
    px_mm = 0.5 * (profile.mm_per_px_x + profile.mm_per_px_y)
    solver = max(1, round(config.solver_cell_mm / px_mm))
    shear = solver * max(1, round(config.shear_cell_mm / px_mm / solver))
    return solver, shear


@dataclass(frozen=True)
class PadRecord:
    """A pad's small per-frame tactile values (its images and maps go to ``GripperSim.pixels``):
    marker positions (N, 2) px, normal force N, shear force (2,) N, slip mm."""

    markers_ref_px: np.ndarray
    markers_px: np.ndarray
    normal_force_n: float
    shear_force_n: np.ndarray
    slip_mm: float


@dataclass
class RecordedFrame:
    """What ``GripperSim`` captures at one recorded frame (robot, objects, set-points, tactile per pad)."""

    time_s: float
    ee_pose: np.ndarray
    opening_m: float
    finger_pos_m: np.ndarray
    ee_setpoint: np.ndarray
    opening_setpoint_m: float
    primitive: int
    objects_world: dict[str, np.ndarray]
    tactile: dict[str, PadRecord]
    object_in_pad: dict[str, np.ndarray]
    pad_world: dict[str, np.ndarray]


@dataclass(frozen=True)
class GeomTexture:
    """Grooves on a cylinder geom that only the tactile gap field sees (``texture.py``)."""

    geom: str
    grooves: CylinderGrooves = field(default_factory=CylinderGrooves)


class GripperSim:
    """A scene, its gripper set-points, and the frames recorded so far.

    ``objects``: the bodies whose world poses are recorded (``scene/objects/{name}/pose``); the first is
    the tactile object, whose pose in each pad frame is recorded too. ``pad_geoms``: per pad, the geoms its
    gap field sees. ``cameras``: scene cameras recorded with every frame. ``textures``: tactile-only grooves.
    """

    def __init__(self, model: mujoco.MjModel, profile: SensorProfile, pad_geoms: dict[str, list[str]],
                 objects: str | Sequence[str], primitive_names: list[str], config: SimConfig | None = None, *,
                 cameras: Sequence[CameraSpec] = (), textures: Sequence[GeomTexture] = ()) -> None:
        self.model, self.data = model, mujoco.MjData(model)
        self.profile = profile
        self.config = config or SimConfig()
        self.pad_geoms = pad_geoms
        self.object_names = [objects] if isinstance(objects, str) else list(objects)
        self._object_ids = {name: model.body(name).id for name in self.object_names}
        self.object_body = self._object_ids[self.object_names[0]]
        self.camera_specs = list(cameras)
        self._rig = CameraRig(model, self.camera_specs) if self.camera_specs else None
        self._textures = [(model.geom(t.geom).id, t.grooves) for t in textures]
        for gid, _ in self._textures:
            if model.geom_type[gid] != mujoco.mjtGeom.mjGEOM_CYLINDER:
                raise ValueError(f"grooves are modelled on cylinder geoms only ({model.geom(gid).name})")
        self._touch_buffers = {pad: GapFieldBuffer(sensor_grid(profile, 1).shape) for pad in PADS}
        self.primitive_names = primitive_names
        self.primitive = -1
        self.frames: list[RecordedFrame] = []
        #: per-pixel recorded arrays by path (``tactile/{pad}/marked_rgb``, ...), filled frame by frame
        self.pixels: dict[str, FrameStack] = {}
        self._grid = sensor_grid(profile, 1)
        self._gap_cutoff_mm = TACTILE_GAP_CUTOFF_MM[self.config.contact_method]
        self._gap_buffers = {pad: GapFieldBuffer(self._grid.shape) for pad in PADS}
        # the geom poses (world) the recorded gap fields were made at: while they hold, touch() reads those
        # fields instead of making its own (an expert reads the pads right after a frame is recorded)
        self._recorded_geom_poses: tuple[np.ndarray, np.ndarray] | None = None
        self._pixel_layout = PixelBuffers.layout(profile.image_height_px, profile.image_width_px)
        solver_step, shear_step = cell_steps(profile, self.config)
        self._tactile = TactileConfig(
            shear_step=shear_step,
            contact=ContactConfig(method=self.config.contact_method, tol=self.config.contact_tol,
                                  solver_step=solver_step, gel=self.config.gel),
        )
        self._states: dict[str, ContactState | None] = {pad: None for pad in PADS}
        # per pad, while in contact: the object-frame point (m) that sat at the pad centre when the contact
        # began, and the object's orientation in the pad frame then
        self._anchors: dict[str, tuple[int, np.ndarray, np.ndarray] | None] = {pad: None for pad in PADS}
        self._slides = [model.joint(f"{pad}_slide").qposadr[0] for pad in PADS]
        self._actuators = [model.actuator(f"{pad}_finger").id for pad in PADS]
        self._ee_site = model.site("ee").id
        self._pad_sites = {pad: model.site(f"{pad}_pad").id for pad in PADS}
        self._gel_geom_ids = {pad: model.geom(f"{pad}_gel").id for pad in PADS}
        self._object_geom_ids = {pad: [model.geom(g).id for g in geoms] for pad, geoms in pad_geoms.items()}
        # the recorded object (or the indenter) each geom belongs to: its own body or the nearest recorded ancestor
        self._geom_body = {}
        recorded = set(self._object_ids.values())
        for geoms in self._object_geom_ids.values():
            for geom in geoms:
                body = int(model.geom_bodyid[geom])
                while body not in recorded and body != 0:
                    body = int(model.body_parentid[body])
                self._geom_body[geom] = body if body in recorded else int(model.geom_bodyid[geom])
        mujoco.mj_forward(model, self.data)
        self.ee_setpoint = np.concatenate([self.data.mocap_pos[0], self.data.mocap_quat[0]])
        self.finger_setpoints_m = self.data.qpos[self._slides].astype(float).copy()
        self.grip_regulator: Callable[[GripperSim], None] | None = None
        self._record_origin_s = 0.0
        self._next_record_s = math.inf  # nothing is recorded before start_recording()

    def start_recording(self) -> None:
        """Record from now on (frame 0 = the next tick, or the next ``record_frame()``), forgetting any
        earlier frames."""
        self.frames.clear()
        capacity = self.config.max_frames or self.config.frame_capacity
        self.pixels = {f"tactile/{pad}/{name}": FrameStack(capacity) for pad in PADS for name in PIXEL_FIELDS}
        for cam in self.camera_specs:
            self.pixels[f"scene/cameras/{cam.name}/rgb"] = FrameStack(capacity)
        self._record_origin_s = self._next_record_s = self.time_s

    def forget_frames(self) -> None:
        """Drop the recorded frames but keep the buffers and the recording clock (an environment that only
        needs its latest observation records one frame a step into the same memory)."""
        self.frames.clear()
        for stack in self.pixels.values():
            stack.clear()

    def record_frame(self) -> RecordedFrame:
        """Record the current state as the next frame now (tactile fields, cameras, poses) and return it."""
        if self.config.max_frames is not None and len(self.frames) >= self.config.max_frames:
            raise FrameBudgetReached
        self._record()
        return self.frames[-1]

    def close(self) -> None:
        """Free the camera renderers (the OpenGL contexts)."""
        if self._rig is not None:
            self._rig.close()

    @property
    def opening_setpoint_m(self) -> float:
        """Commanded distance between the gel surfaces, m (from the two finger set-points)."""
        return float(finger_pos_to_opening(float(np.mean(self.finger_setpoints_m))))

    def set_opening(self, opening_m: float) -> None:
        """Command both fingers symmetrically to a gel-to-gel distance, m."""
        self.finger_setpoints_m[:] = opening_to_finger_pos(opening_m)

    # --- state -----------------------------------------------------------------------------------
    @property
    def time_s(self) -> float:
        return float(self.data.time)

    @property
    def dt_s(self) -> float:
        return float(self.model.opt.timestep) * self.config.control_period_steps

    @property
    def opening_m(self) -> float:
        """Distance between the two gel surfaces now, m."""
        q = self.data.qpos[self._slides]
        return float(finger_pos_to_opening(float(np.mean(q))))

    def finger_positions_m(self) -> np.ndarray:
        """(2,) slide positions of the left and right finger now, m (0 = fully open)."""
        return self.data.qpos[self._slides].astype(float)

    def ee_pose(self) -> np.ndarray:
        return np.concatenate([self.data.site_xpos[self._ee_site],
                               mat_to_quat(self.data.site_xmat[self._ee_site].reshape(3, 3))])

    def touch(self) -> dict[str, TouchReading]:
        """What each pad feels now (``touch.read_touch``: contact patch, centroid, direction, depth, fill),
        from the same gap field, grooves included, that the tactile images are made from."""
        out = {}
        grid = self._grid
        if self._recorded_fields_current():
            # the recorded fields hold the same overlap: their cut-off (0 or 2 mm) only changes what reads far
            return {pad: read_touch(self._gap_buffers[pad].gap_mm, grid, self._gap_buffers[pad].box) for pad in PADS}
        for pad in PADS:
            field_buffer = self._touch_buffers[pad]
            pose = pad_pose(self.model, self.data, f"{pad}_pad")
            gap = gap_field(self.model, self.data, pose, self.pad_geoms[pad], grid, cutoff_mm=1.0, out=field_buffer)
            self._apply_textures(gap, field_buffer.box, pose)
            out[pad] = read_touch(gap, grid, field_buffer.box)
        return out

    def _recorded_fields_current(self) -> bool:
        """Whether the last recorded frame's gap fields are those of the geoms now (no step since)."""
        poses = self._recorded_geom_poses
        return (poses is not None and np.array_equal(poses[0], self.data.geom_xpos)
                and np.array_equal(poses[1], self.data.geom_xmat))

    def _apply_textures(self, gap: np.ndarray, box: tuple[slice, slice], pose: PadPose) -> None:
        for gid, grooves in self._textures:
            add_cylinder_grooves(gap, box, self._grid, pose, self.data.geom_xpos[gid],
                                 self.data.geom_xmat[gid].reshape(3, 3), float(self.model.geom_size[gid][0]), grooves)

    def object_pose(self, name: str) -> np.ndarray:
        """(7,) world pose of a recorded object now: x, y, z (m), quaternion w, x, y, z."""
        body = self._object_ids[name]
        return np.concatenate([self.data.xpos[body], mat_to_quat(self.data.xmat[body].reshape(3, 3))])

    def object_gaps_mm(self) -> dict[str, dict[str, float]]:
        """Per recorded object, per pad: the signed pad-object distance now, mm (as ``gap_mm``, object by
        object; capped at ``GAP_PROBE_MAX_MM``). An object both pads overlap is the one held."""
        out: dict[str, dict[str, float]] = {}
        for name, body in self._object_ids.items():
            out[name] = {}
            for pad in PADS:
                gel = self._gel_geom_ids[pad]
                dists = [mujoco.mj_geomDistance(self.model, self.data, gel, geom, GAP_PROBE_MAX_MM / 1000, None)
                         for geom in self._object_geom_ids[pad] if self._geom_body[geom] == body]
                out[name][pad] = min(dists, default=GAP_PROBE_MAX_MM / 1000) * 1000.0
        return out

    def _touched_body(self, pad: str) -> int:
        """The body of the geom nearest the pad now (the one a pad in contact is touching)."""
        gel = self._gel_geom_ids[pad]
        nearest = min(self._object_geom_ids[pad], key=lambda geom: mujoco.mj_geomDistance(
            self.model, self.data, gel, geom, GAP_PROBE_MAX_MM / 1000, None))
        return int(self._geom_body[nearest])

    def gap_mm(self) -> dict[str, float]:
        """Signed distance between each gel pad and the object now, mm: negative is the indentation the
        grasp law reads, positive the distance still to close (capped at ``GAP_PROBE_MAX_MM``).

        MuJoCo's narrow-phase distance between the rigid pad and each object geom: the same penetration its
        contacts use, at microseconds a call (a full gap field every control tick would dominate the run).
        """
        out = {}
        for pad in PADS:
            gel = self._gel_geom_ids[pad]
            out[pad] = min(mujoco.mj_geomDistance(self.model, self.data, gel, geom, GAP_PROBE_MAX_MM / 1000, None)
                           for geom in self._object_geom_ids[pad]) * 1000.0
        return out

    # --- stepping --------------------------------------------------------------------------------
    def tick(self) -> None:
        """Apply the set-points and advance one control period, recording frames that fall due."""
        if self.grip_regulator is not None:
            self.grip_regulator(self)
        self.data.mocap_pos[0] = self.ee_setpoint[:3]
        self.data.mocap_quat[0] = self.ee_setpoint[3:]
        self.finger_setpoints_m = np.clip(self.finger_setpoints_m, 0.0, FINGER_TRAVEL_M)
        self.data.ctrl[self._actuators] = self.finger_setpoints_m
        for _ in range(self.config.control_period_steps):
            if self.config.record_rate_hz is not None and self.time_s + 1e-12 >= self._next_record_s:
                if self.config.max_frames is not None and len(self.frames) >= self.config.max_frames:
                    raise FrameBudgetReached
                self._record()
            mujoco.mj_step(self.model, self.data)

    def _record(self) -> None:
        model, data = self.model, self.data
        obj_pos, obj_mat = data.xpos[self.object_body], data.xmat[self.object_body].reshape(3, 3)
        tactile, in_pad, pad_world = {}, {}, {}
        for pad in PADS:
            site = self._pad_sites[pad]
            pad_pos, pad_mat = data.site_xpos[site], data.site_xmat[site].reshape(3, 3)
            rel = relative_pose(pad_pos, pad_mat, obj_pos, obj_mat)
            field = self._gap_buffers[pad]
            pose = pad_pose(model, data, f"{pad}_pad")
            gap = gap_field(model, data, pose, self.pad_geoms[pad], self._grid, cutoff_mm=self._gap_cutoff_mm, out=field)
            if self._textures:
                self._apply_textures(gap, field.box, pose)
            near = gap[field.box]
            touching = bool(near.size) and float(near.min()) < 0.0
            tangential_mm, twist_rad = self._motion_since_onset(pad, touching, pad_pos, pad_mat)
            stacks = {name: self.pixels[f"tactile/{pad}/{name}"] for name in PIXEL_FIELDS}
            rows = PixelBuffers(**{name: stack.next_row(*self._pixel_layout[name]) for name, stack in stacks.items()})
            frame = simulate_frame(
                self.profile, gap, method=self.config.contact_method,
                tangential_mm=tangential_mm, twist_rad=twist_rad, state=self._states[pad], config=self._tactile,
                out=rows, gap_box=field.box,
            )
            for stack in stacks.values():
                stack.commit()
            self._states[pad] = frame.state
            tactile[pad] = PadRecord(frame.markers_ref_px, frame.markers_px, float(frame.normal_force_n),
                                     frame.shear_force_n, float(frame.slip_mm))
            in_pad[pad] = rel
            pad_world[pad] = np.concatenate([pad_pos, mat_to_quat(pad_mat)])
        self._recorded_geom_poses = (data.geom_xpos.copy(), data.geom_xmat.copy())
        if self._rig is not None:
            for cam in self.camera_specs:
                stack = self.pixels[f"scene/cameras/{cam.name}/rgb"]
                self._rig.render(data, cam, out=stack.next_row((cam.height_px, cam.width_px, 3), np.uint8))
                stack.commit()
        objects_world = {name: np.concatenate([data.xpos[body], mat_to_quat(data.xmat[body].reshape(3, 3))])
                         for name, body in self._object_ids.items()}
        recorded = RecordedFrame(
            time_s=self.time_s - self._record_origin_s, ee_pose=self.ee_pose(), opening_m=self.opening_m,
            finger_pos_m=data.qpos[self._slides].astype(np.float32).copy(), ee_setpoint=self.ee_setpoint.copy(),
            opening_setpoint_m=self.opening_setpoint_m, primitive=self.primitive,
            objects_world=objects_world, tactile=tactile, object_in_pad=in_pad,
            pad_world=pad_world,
        )
        self.frames.append(recorded)
        if self.config.record_rate_hz is not None:
            self._next_record_s = self._record_origin_s + len(self.frames) / self.config.record_rate_hz

    def _motion_since_onset(self, pad: str, touching: bool, pad_pos: np.ndarray,
                            pad_mat: np.ndarray) -> tuple[tuple[float, float], float]:
        """Tangential displacement (pad x, y, mm) and twist about the pad normal (rad), since this contact
        began, of the object the pad touches (with several objects in a scene, the one nearest the pad; a
        change of object is a new contact).

        The displacement is that of the object's material point that sat at the pad centre at onset: the
        shear model needs the motion at the gel surface, and the object's origin, far behind the surface,
        would turn every tilt into a slide. The twist is read from the rotation since onset, which stays
        near the identity (the object's own axes may be aligned with the pad normal, where an angle read
        from them is undefined).
        """
        if not touching:   # no overlap in the pad's gap field
            self._anchors[pad] = None
            return (0.0, 0.0), 0.0
        body = self.object_body if len(self._object_ids) == 1 else self._touched_body(pad)
        obj_pos, obj_mat = self.data.xpos[body], self.data.xmat[body].reshape(3, 3)
        if self._anchors[pad] is None or self._anchors[pad][0] != body:  # type: ignore[index]
            self._anchors[pad] = (body, obj_mat.T @ (pad_pos - obj_pos), pad_mat.T @ obj_mat)
        _, anchor, onset_rel = self._anchors[pad]  # type: ignore[misc]
        in_pad = pad_mat.T @ (obj_pos + obj_mat @ anchor - pad_pos)
        turn = (pad_mat.T @ obj_mat) @ onset_rel.T
        twist = float(np.arctan2(turn[1, 0] - turn[0, 1], turn[0, 0] + turn[1, 1]))
        return (float(in_pad[0] * 1000), float(in_pad[1] * 1000)), twist

    def set_primitive(self, name: str) -> None:
        if name not in self.primitive_names:
            raise ValueError(f"primitive {name!r} is not in {self.primitive_names}")
        self.primitive = self.primitive_names.index(name)

    def pixel_arrays(self) -> dict[str, np.ndarray]:
        """The recorded per-pixel arrays, (T, ...) each, by path."""
        return {path: stack.array() for path, stack in self.pixels.items()}

    def reference_rgb(self) -> np.ndarray:
        """(H, W, 3) uint8 I_pure of an undeformed gel with this simulation's optics (``pure_ref_rgb``)."""
        return render_reference(self.profile, self._tactile)

    def finite(self) -> bool:
        return bool(np.isfinite(self.data.qpos).all() and np.isfinite(self.data.qvel).all())
