"""The contact step's contract: configuration, result, and the dispatch over the two methods.

``solve_contact(gap_mm, grid, material, config)`` turns a gap field on a grid into the deformed gel surface.
One method per file: :mod:`.contact_geometric` (Hertz's footprint and load from the overlap, with a
half-space-shaped sink-in around it; cheap) and
:mod:`.contact_elastic` (linear-elastic bonded layer or half-space, Polonsky & Keer conjugate gradient).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from univtac_data.schema.sensors import Material

from .sensor_model import SensorGrid

__all__ = ["ContactConfig", "ContactMethod", "ContactResult", "GelModel", "solve_contact"]

ContactMethod = Literal["geometric", "elastic"]
GelModel = Literal["layer", "half_space"]

GAP_FAR_MM = 1.0e3
"""Gap value meaning 'no object along this ray', mm (any value well above every indentation works)."""


@dataclass(frozen=True)
class ContactConfig:
    """How to solve the contact. Defaults meet the Hertz accuracy targets at the sensors' native sizes."""

    method: ContactMethod = "elastic"
    solver_step: int = 2  # image pixels per solver cell along each axis (elastic); 1 = native resolution
    tol: float = 1e-6  # elastic: relative change of the pressure field that stops the CG
    max_iter: int = 300  # elastic: CG iteration cap (convergence is reported in ContactResult.converged)
    # elastic: solve window = overlap bounding box grown by this fraction per side (at least 2 cells). The
    # pressure is zero off the overlap, so a margin only enlarges the transforms: 0.5 cost 35 % more time.
    window_margin: float = 0.0
    # elastic: "half_space", whose closed forms (Hertz, Boussinesq) the solver meets exactly and against which
    # the rigid pad's contact is calibrated, or "layer", the gel as a layer of the profile's thickness bonded
    # to a rigid backing: stiffer, and its deformation stays within a few thicknesses of the contact
    gel: GelModel = "half_space"
    # geometric: the gel touches the object where the overlap exceeds this fraction of the piece's deepest
    # overlap (1/2: Hertz's radius sqrt(R d) for a sphere, the whole face for a flat punch)
    contact_fraction: float = 0.5
    # geometric: the sink-in around the contact follows the half-space's out to this many contact radii
    # (measured from the centre), then ends smoothly about three times further
    tail_start: float = 2.0


@dataclass(frozen=True)
class ContactResult:
    """Deformed surface and loads of one pad, on the grid the solver ran on.

    ``depth_mm``: (ny, nx) float64 indentation of the gel surface toward the camera, mm, >= 0.
    ``pressure_mpa``: (ny, nx) float64 normal pressure, MPa, >= 0. ``contact_mask``: (ny, nx) bool, p > 0
    (elastic) or overlap > 0 (geometric). ``normal_force_n``: total normal load, N.
    ``iterations``/``converged``: elastic CG bookkeeping (0/True for the geometric method).
    ``box``: (rows, cols) slices outside which depth and pressure are zero and the mask is false, when the
    solver knows it (the geometric one does); None: anywhere.
    """

    depth_mm: np.ndarray
    pressure_mpa: np.ndarray
    contact_mask: np.ndarray
    normal_force_n: float
    iterations: int = 0
    converged: bool = True
    box: tuple[slice, slice] | None = None


def solve_contact(gap_mm: np.ndarray, grid: SensorGrid, material: Material, config: ContactConfig,
                  initial_pressure_mpa: np.ndarray | None = None, thickness_mm: float | None = None,
                  gap_box: tuple[slice, slice] | None = None) -> ContactResult:
    """Solve the normal contact of a gap field (ny, nx) mm (negative = overlap) on ``grid``.

    ``initial_pressure_mpa`` (ny, nx), e.g. the previous frame's: a starting point for the elastic solve
    (the solution does not depend on it, only the iterations do). ``thickness_mm``: the gel layer's
    thickness, used by the elastic method when ``config.gel`` is "layer" (which then requires it).
    ``gap_box``: (rows, cols) outside which the gap is positive, if known; the geometric method then
    looks for the overlap only there."""
    if gap_mm.shape != grid.shape:
        raise ValueError(f"gap field shape must match the grid {grid.shape} (got {gap_mm.shape})")
    if config.method == "geometric":
        from .contact_geometric import solve_geometric

        return solve_geometric(gap_mm, grid, material, config, gap_box)
    if config.method == "elastic":
        from .contact_elastic import solve_elastic

        if config.gel not in ("layer", "half_space"):
            raise ValueError(f"ContactConfig.gel must be 'layer' or 'half_space' (got {config.gel!r})")
        if config.gel == "layer" and thickness_mm is None:
            raise ValueError("ContactConfig.gel='layer' needs the gel thickness (thickness_mm)")
        return solve_elastic(gap_mm, grid, material, config, initial_pressure_mpa,
                             thickness_mm if config.gel == "layer" else None)
    raise ValueError(f"contact method must be 'geometric' or 'elastic' (got {config.method!r})")
