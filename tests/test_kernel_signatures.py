"""Each compiled tactile kernel compiles once per process: the arrays a frame hands it have one dtype, layout
and writeability whatever the contact. A kernel that sees a second signature compiles again (seconds, in
every fresh worker; a task episode with one tiny contact cost 10 s of compiling), so a contact of one pixel,
a contact of hundreds of cells, a slide carried across frames and both contact models must all reach the
kernels through the same signatures."""

from __future__ import annotations

import json
import os
import subprocess
import sys

PROBE = r"""
import collections, json
import numba
from numba.core.dispatcher import _DispatcherBase
import numpy as np

# the signatures each kernel is asked for from Python (a call whose types have no compiled version yet): kernels
# compiled inside other kernels for several types are compiled with their caller, not again per call
asked = collections.defaultdict(set)
compile_for_args = _DispatcherBase._compile_for_args


def recording(self, *args, **kwargs):
    asked[f"{self.py_func.__module__}.{self.py_func.__name__}"].add(str(tuple(numba.typeof(a) for a in args)))
    return compile_for_args(self, *args, **kwargs)


_DispatcherBase._compile_for_args = recording
import univtac_data.generators.tactile as tactile
from univtac_data import get_sensor
from univtac_data.generators.tactile import ContactConfig, TactileConfig, simulate_frame, sphere_gap

for sensor in ("gelsight_mini", "xense_ws"):
    profile = get_sensor(sensor)
    h, w = sphere_gap(profile, radius_mm=5.0, depth_mm=0.1).shape
    one_pixel = np.full((h, w), 1.0)
    one_pixel[h // 2, w // 2] = -0.01
    for method in ("geometric", "elastic"):
        config = TactileConfig(contact=ContactConfig(method=method))
        state = None
        # a one-pixel contact found in a one-pixel box, then a growing press that slides and twists, carrying
        # the contact state from frame to frame (warm starts), then the one pixel again
        frames = [(one_pixel, (slice(h // 2, h // 2 + 1), slice(w // 2, w // 2 + 1)), (0.0, 0.0), 0.0)]
        for k, depth in enumerate((0.05, 0.2, 0.4, 0.6)):
            frames.append((sphere_gap(profile, radius_mm=5.0, depth_mm=depth), None, (0.02 * k, 0.01 * k), 0.002 * k))
        # a press wide enough for the shear's FFT operator (the ones above take its dense matrix)
        frames.append((sphere_gap(profile, radius_mm=30.0, depth_mm=1.0), None, (0.1, 0.05), 0.01))
        frames.append((one_pixel, None, (0.1, 0.0), 0.0))
        for gap, box, tangential, twist in frames:
            frame = simulate_frame(profile, gap, method=method, tangential_mm=tangential, twist_rad=twist,
                                   state=state, config=config, gap_box=box)
            state = frame.state

print(json.dumps({name: sorted(sigs) for name, sigs in asked.items() if name.startswith(tactile.__name__)}))
"""


def test_every_tactile_kernel_compiles_one_signature_whatever_the_contact():
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=900,
                          env={**os.environ, "MUJOCO_GL": "egl"})
    assert done.returncode == 0, done.stderr
    signatures = json.loads(done.stdout.strip().splitlines()[-1])
    assert len(signatures) >= 10, signatures  # the probe reached the kernels
    several = {name: sigs for name, sigs in signatures.items() if len(sigs) > 1}
    assert not several, json.dumps(several, indent=1)
