"""Tactile module: contact geometry -> depth, pressure, forces, markers, slip and tactile images.

Pipeline for one pad and one frame (docs/tactile.md):
``gap_field`` (MuJoCo scene -> gap on the pad grid) -> ``simulate_frame`` (contact solve, ``"geometric"`` or
``"elastic"``; shear, markers and slip; shaded or Taxim-calibrated optics) -> ``TactileFrame`` (the format's
per-pad fields) -> ``contact_sheet`` (a PNG to look at).
"""

from .contact import GAP_FAR_MM, ContactConfig, ContactResult, GelModel, solve_contact
from .contact_sheet import SheetFrame, contact_sheet, image_gallery
from .frame import PixelBuffers, TactileConfig, TactileFrame, render_reference, simulate_frame
from .gap_field import GapFieldBuffer, PadPose, gap_field, pad_pose
from .indenters import DEMO_INDENTERS, cross_gap, cylinder_gap, demo_gap, punch_gap, sphere_gap
from .optics import ShadingConfig, render_shaded
from .optics_calibrated import TaximCalibration, load_taxim_calibration, taxim_calibration_dir
from .sensor_model import SensorGrid, marker_reference_mm, marker_reference_px, project_to_px, sensor_grid
from .shear import ContactState

__all__ = [
    "DEMO_INDENTERS", "GAP_FAR_MM", "ContactConfig", "ContactResult", "ContactState", "GapFieldBuffer", "GelModel",
    "PadPose", "PixelBuffers", "SensorGrid", "ShadingConfig", "SheetFrame", "TactileConfig", "TactileFrame",
    "TaximCalibration", "contact_sheet",
    "cross_gap", "cylinder_gap", "demo_gap", "gap_field", "image_gallery", "load_taxim_calibration", "marker_reference_mm",
    "marker_reference_px", "pad_pose", "project_to_px", "punch_gap", "render_reference", "render_shaded", "sensor_grid",
    "simulate_frame", "solve_contact", "sphere_gap", "taxim_calibration_dir",
]
