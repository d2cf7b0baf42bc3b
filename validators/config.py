"""Thresholds of the validators: one typed, frozen config with the unit in every name.

Sensor-specific limits (safe indentation, gel thickness, marker radius, image size) come from the
episode's ``SensorProfile``, not from here. Defaults are documented in ``spec/validation.md``.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class ValidationConfig(BaseModel):
    """Every threshold a rule compares against, except those of the sensor profile."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    # --- safety -------------------------------------------------------------------------------------
    max_slip_held_mm: float = Field(
        default=1.0, gt=0, description="most slip_mm allowed on a pad while the object is held, mm")
    held_normal_force_n: float = Field(
        default=0.1, gt=0, description="normal force on every pad above which the object counts as held, N")
    max_normal_force_n: float = Field(
        default=30.0, gt=0, description="upper bound of a pad's normal (grasp) force, N; the lower bound is 0")
    summary_tolerance_mm: float = Field(
        default=1e-3, ge=0, description="meta.safety indentation and slip may differ from the arrays by this, mm")
    summary_tolerance_n: float = Field(
        default=1e-3, ge=0, description="meta.safety force may differ from the arrays by this, N")
    # --- physics: values and poses -------------------------------------------------------------------
    quaternion_norm_tolerance: float = Field(
        default=1e-3, gt=0, description="largest allowed abs(norm(q) - 1) of a stored quaternion, dimensionless")
    max_linear_speed_m_s: float = Field(
        default=5.0, gt=0,
        description="fastest a pose may translate between two frames, m/s (an object dropped 1.2 m reaches 4.9)")
    max_angular_speed_rad_s: float = Field(
        default=20.0, gt=0, description="fastest a pose may rotate between two frames, rad/s (about 3 turns/s)")
    timestamp_tolerance_fraction: float = Field(
        default=0.05, gt=0, lt=1,
        description="each frame interval may differ from 1e9 / nominal_rate_hz ns by this fraction of it")
    # --- physics: contact and markers ----------------------------------------------------------------
    contact_force_tolerance_n: float = Field(
        default=1e-3, ge=0, description="a pad's normal force at or below this counts as zero, N")
    marker_rest_tolerance_px: float = Field(
        default=2.0, gt=0, description="distance a marker may sit from its reference when nothing touches, px")
    marker_clearance_px: float = Field(
        default=2.0, ge=0,
        description="pixels farther than marker_radius_px + this from every current marker are 'away', px")
    marked_pure_tolerance_levels: int = Field(
        default=0, ge=0, le=255, description="largest abs(I_marked - I_pure) allowed away from markers, uint8 levels")
    reference_tolerance_levels: float = Field(
        default=2.0, ge=0, le=255,
        description="largest mean abs(I_pure - pure_ref_rgb) allowed on a frame without indentation, uint8 "
                    "levels (sensor noise of a few levels averages below it)")
    # --- physics: kinetic energy ---------------------------------------------------------------------
    gravity_m_s2: float = Field(
        default=9.81, gt=0, description="the most gravity can add to an object's speed per second, m/s^2")
    contact_speed_factor: float = Field(
        default=2.0, ge=1,
        description="an object may leave a contact at up to this multiple of the pusher's speed "
                    "(2: elastic impact of a light object by a heavy one), dimensionless")
    lever_arm_max_m: float = Field(
        default=0.3, gt=0, description="largest distance from the gripper at which its rotation moves an object, m")
    speed_tolerance_m_s: float = Field(
        default=0.05, ge=0, description="speed an object may gain beyond the explained budget (noise), m/s")
    # --- tasks ---------------------------------------------------------------------------------------
    camera_blank_std_levels: float = Field(
        default=1.0, ge=0, description="a scene camera frame whose pixel values spread less than this is blank, "
                                       "uint8 levels")
    # --- schema: unit plausibility -------------------------------------------------------------------
    max_position_m: float = Field(
        default=10.0, gt=0,
        description="largest abs(x), abs(y), abs(z) of a stored position (catches mm stored as m), m")
    max_gripper_width_m: float = Field(
        default=0.3, gt=0, description="largest gripper width, finger position or commanded width, m")
    gripper_negative_tolerance_m: float = Field(
        default=1e-3, ge=0, description="how far below 0 a gripper width or finger position may go, m")
    # --- reporting and reading -----------------------------------------------------------------------
    max_listed_frames: int = Field(
        default=20, gt=0, description="offending frames listed per finding (the count is always complete)")
    read_block_frames: int = Field(
        default=16, gt=0, description="frames of an image or depth array read at once (bounds memory)")
