"""Sensor profiles: the three visuo-tactile sensors as data.

Figures are public (UniVTAC configs, vendor pages; the source is written beside each number). The
elastic constants are our choice for soft silicone (no vendor publishes them); the source is written
beside each number. Geometry conventions, used by every module:

* gel-pad-centre frame: origin at the centre of the undeformed gel surface; +z is the outward pad
  normal (from the gel toward the object); +x along increasing image column, +y along increasing image
  row. It is the sensor camera's frame (OpenCV: x right, y down, z forward) moved to the gel surface,
  right-handed. Units: m in stored poses, mm in profile geometry.
* imaged area (mm) maps to the full image; pinhole intrinsics fx = W * camera_to_surface / imaged_width.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field, computed_field, model_validator


class Light(BaseModel):
    """One LED of the sensor's illumination (used by the physically shaded optical model)."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    azimuth_deg: float = Field(description="direction of the light in the gel plane, deg from +x toward +y")
    elevation_deg: float = Field(description="angle of the light above the gel plane, deg (grazing: small)")
    rgb: tuple[float, float, float] = Field(description="linear colour of the light, each channel in [0, 1]")


class Optics(BaseModel):
    """How the sensor's camera sees the gel: lights, background tint, vignetting, marker colour."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    lights: tuple[Light, ...]
    background_rgb: tuple[int, int, int] = Field(description="flat, untouched gel colour, uint8 RGB")
    vignetting: float = Field(ge=0.0, le=1.0, description="brightness loss at the image corners, fraction")
    marker_rgb: tuple[int, int, int] = Field(description="colour of the printed markers, uint8 RGB")


class Material(BaseModel):
    """Linear-elastic constants of the gel."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    youngs_modulus_mpa: float = Field(gt=0, description="Young's modulus E, MPa")
    poisson_ratio: float = Field(ge=0.0, le=0.5, description="Poisson's ratio nu, dimensionless")
    friction: float = Field(gt=0, description="Coulomb friction coefficient gel/object")
    source: str = Field(description="where the numbers come from")


class SensorProfile(BaseModel):
    """Everything the format and the tactile model need to know about one sensor model."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    name: str = Field(description="stable identifier used in files and on the command line")
    display_name: str
    image_width_px: int = Field(gt=0)
    image_height_px: int = Field(gt=0)
    imaged_width_mm: float = Field(gt=0, description="extent of the gel seen across the image width, mm")
    imaged_height_mm: float = Field(gt=0, description="extent of the gel seen across the image height, mm")
    camera_to_surface_mm: float = Field(gt=0, description="pinhole distance from camera to gel surface, mm")
    gel_width_mm: float = Field(gt=0, description="gel pad extent along image x, mm")
    gel_height_mm: float = Field(gt=0, description="gel pad extent along image y, mm")
    gel_thickness_mm: float = Field(gt=0, description="gel layer thickness, mm")
    marker_cols: int = Field(gt=0, description="markers along image x")
    marker_rows: int = Field(gt=0, description="markers along image y")
    marker_pitch_x_mm: float = Field(gt=0)
    marker_pitch_y_mm: float = Field(gt=0)
    marker_radius_px: float = Field(gt=0)
    frame_rate_hz: float | None = Field(default=None, description="the real sensor's camera rate, Hz")
    material: Material
    safe_indentation_mm: float = Field(gt=0, description="deepest indentation considered safe, mm")
    grasp_threshold_mm: float = Field(gt=0, description="UniVTAC's closed-loop grasp depth delta_th, mm")
    optics: Optics

    def __hash__(self) -> int:
        # the tactile model's caches are keyed by profile, a dozen lookups a generated frame, and the default
        # hash walks every field of the profile, its material and its optics each time; equal profiles have
        # equal names, so the name alone is a valid hash
        return hash(self.name)

    @model_validator(mode="before")
    @classmethod
    def _derived_fields_agree(cls, data: Any) -> Any:
        """``info.json`` carries the derived intrinsics for readers in other languages; on reading them
        back, check they agree with the primary figures instead of rejecting them as unknown keys."""
        if not isinstance(data, dict) or not any(k in data for k in _DERIVED):
            return data
        data = dict(data)
        given = {k: data.pop(k) for k in _DERIVED if k in data}
        derived = cls.model_validate(data)
        for key, value in given.items():
            if abs(float(getattr(derived, key)) - float(value)) > 1e-6 * max(1.0, abs(float(value))):
                raise ValueError(f"{key} is {value} but the profile's figures give {getattr(derived, key)}")
        return data

    @computed_field  # type: ignore[prop-decorator]
    @property
    def fx_px(self) -> float:
        """Focal length along x, px."""
        return self.image_width_px * self.camera_to_surface_mm / self.imaged_width_mm

    @computed_field  # type: ignore[prop-decorator]
    @property
    def fy_px(self) -> float:
        """Focal length along y, px."""
        return self.image_height_px * self.camera_to_surface_mm / self.imaged_height_mm

    @computed_field  # type: ignore[prop-decorator]
    @property
    def cx_px(self) -> float:
        return (self.image_width_px - 1) / 2.0

    @computed_field  # type: ignore[prop-decorator]
    @property
    def cy_px(self) -> float:
        return (self.image_height_px - 1) / 2.0

    @computed_field  # type: ignore[prop-decorator]
    @property
    def n_markers(self) -> int:
        return self.marker_cols * self.marker_rows

    @property
    def mm_per_px_x(self) -> float:
        return self.imaged_width_mm / self.image_width_px

    @property
    def mm_per_px_y(self) -> float:
        return self.imaged_height_mm / self.image_height_px


_DERIVED = ("fx_px", "fy_px", "cx_px", "cy_px", "n_markers")

_SILICONE_NOTE = (
    "E: soft silicone, order 0.1-1 MPa (the range of silicone elastomers used for gel pads); our choice, no "
    "vendor figure. "
    "nu: near-incompressible silicone (0.45-0.5)."
)

# Three LEDs 120 deg apart at grazing elevation, the GelSight layout; Xense and ViTai use similar
# coloured rings. Tuned by eye against published images, not calibrated.
_RGB_RING = (
    Light(azimuth_deg=90.0, elevation_deg=25.0, rgb=(1.0, 0.15, 0.15)),
    Light(azimuth_deg=210.0, elevation_deg=25.0, rgb=(0.15, 1.0, 0.15)),
    Light(azimuth_deg=330.0, elevation_deg=25.0, rgb=(0.15, 0.15, 1.0)),
)

GELSIGHT_MINI = SensorProfile(
    name="gelsight_mini",
    display_name="GelSight Mini",
    image_width_px=320,
    image_height_px=240,
    imaged_width_mm=26.6,
    imaged_height_mm=20.9,
    camera_to_surface_mm=28.3,
    gel_width_mm=25.25,
    gel_height_mm=20.75,
    gel_thickness_mm=4.0,
    marker_cols=9,
    marker_rows=7,
    marker_pitch_x_mm=2.41,
    marker_pitch_y_mm=2.46,
    marker_radius_px=6.0,
    frame_rate_hz=25.0,
    material=Material(
        youngs_modulus_mpa=0.30,
        poisson_ratio=0.48,
        friction=1.0,
        source="Shore 00-55 (vendor) ~ 0.3 MPa. " + _SILICONE_NOTE,
    ),
    safe_indentation_mm=1.5,
    grasp_threshold_mm=0.5,
    optics=Optics(lights=_RGB_RING, background_rgb=(122, 128, 130), vignetting=0.25, marker_rgb=(20, 20, 20)),
)

GF225 = SensorProfile(
    name="gf225",
    display_name="ViTai GF225",
    image_width_px=480,
    image_height_px=480,
    imaged_width_mm=23.5,
    imaged_height_mm=25.0,
    camera_to_surface_mm=29.0,
    gel_width_mm=27.0,
    gel_height_mm=29.0,
    gel_thickness_mm=2.0,
    marker_cols=9,
    marker_rows=9,
    marker_pitch_x_mm=2.0,
    marker_pitch_y_mm=2.0,
    marker_radius_px=8.0,
    frame_rate_hz=30.0,
    material=Material(youngs_modulus_mpa=0.50, poisson_ratio=0.48, friction=1.0, source=_SILICONE_NOTE),
    safe_indentation_mm=0.8,
    grasp_threshold_mm=0.2,
    optics=Optics(lights=_RGB_RING, background_rgb=(140, 136, 128), vignetting=0.3, marker_rgb=(25, 25, 25)),
)

XENSE_WS = SensorProfile(
    name="xense_ws",
    display_name="Xense WS",
    image_width_px=320,
    image_height_px=240,
    imaged_width_mm=29.3,
    imaged_height_mm=17.5,
    camera_to_surface_mm=24.5,
    gel_width_mm=29.37,
    gel_height_mm=17.48,
    gel_thickness_mm=2.17,
    marker_cols=20,
    marker_rows=11,
    marker_pitch_x_mm=1.15,
    marker_pitch_y_mm=1.2,
    marker_radius_px=2.0,
    frame_rate_hz=None,
    material=Material(youngs_modulus_mpa=0.40, poisson_ratio=0.48, friction=1.0, source=_SILICONE_NOTE),
    safe_indentation_mm=0.8,
    grasp_threshold_mm=0.2,
    optics=Optics(lights=_RGB_RING, background_rgb=(118, 124, 136), vignetting=0.2, marker_rgb=(15, 15, 15)),
)

SENSORS: dict[str, SensorProfile] = {s.name: s for s in (GELSIGHT_MINI, GF225, XENSE_WS)}

# The GelSight Mini imaged over the field of Taxim's real-Mini calibration (640 x 480 px at 0.0295 mm/px,
# 18.88 x 14.16 mm) instead of UniVTAC's 26.6 x 20.9 mm, at the same 320 x 240 pixels (0.059 mm/px, square):
# calibrated images then use the calibration at its own scale, where the default profile stretches it 1.4x.
# Markers: the same physical dots (radius 6 px at 0.083 mm/px -> 8.5 px) and pitch, the 7 x 5 that the field
# holds. A named variant, not one of SENSORS (``generate --sensor all`` and the format's sensor list are unchanged).
GELSIGHT_MINI_CALIBRATED_FIELD = GELSIGHT_MINI.model_copy(update={
    "name": "gelsight_mini_calibrated_field",
    "display_name": "GelSight Mini (calibrated field)",
    "imaged_width_mm": 18.88,
    "imaged_height_mm": 14.16,
    "marker_cols": 7,
    "marker_rows": 5,
    "marker_radius_px": 8.5,
})

SENSOR_VARIANTS: dict[str, SensorProfile] = {GELSIGHT_MINI_CALIBRATED_FIELD.name: GELSIGHT_MINI_CALIBRATED_FIELD}
"""Named profiles beside SENSORS, found by ``get_sensor``: other fields of view of the same hardware."""

FIELD_OF_VIEW_NOTES: tuple[str, ...] = (
    "GelSight Mini: `gelsight_mini` follows UniVTAC's configuration, for parity with its data: 26.6 x 20.9 mm "
    "imaged, wider than the 25.25 x 20.75 mm gel pad, with non-square pixels of 0.083 x 0.087 mm. The real "
    "sensor images less: the vendor's 0.0634 mm/px gives about 20.3 x 15.2 mm at 320 x 240, and Taxim's "
    "real-Mini calibration covers 18.88 x 14.16 mm (640 x 480 at 0.0295 mm/px), so calibrated images of "
    "`gelsight_mini` stretch the calibration 1.4x across the image. The named variant "
    "`gelsight_mini_calibrated_field` (`get_sensor`, not in the sensor list above) images exactly the "
    "calibration's field at 320 x 240 (0.059 mm/px, square pixels, the 7 x 5 markers it holds), so the "
    "calibrated renderer uses the calibration at its own scale.",
)


def get_sensor(name: str) -> SensorProfile:
    """Look a profile up by name (SENSORS, then SENSOR_VARIANTS); the error lists the known names."""
    try:
        return SENSORS[name] if name in SENSORS else SENSOR_VARIANTS[name]
    except KeyError:
        raise KeyError(f"unknown sensor {name!r}; known sensors: {', '.join([*SENSORS, *SENSOR_VARIANTS])}") \
            from None
