"""An episode logged for the Rerun viewer (``univtac-data preview PATH --rerun FILE.rrd``; then ``rerun FILE.rrd``).

Entity paths, all on the ``frame`` timeline (sequence = frame index) and the ``time`` timeline (the recorded
``timestamps_ns``)::

    tactile/{pad}/marked            Image, I_marked
    tactile/{pad}/marked/markers    Points2D, the current marker centres (u, v) px over I_marked
    tactile/{pad}/depth             DepthImage, indentation in um (meter = 1e6)
    tactile/{pad}/normal_force_n    Scalars; likewise slip_mm
    cameras/{camera}/rgb            Image; cameras/{camera}/depth: DepthImage in m, when recorded
    world/ee                        Transform3D, robot/ee_pose (world frame)
    world/pads/{pad}                Transform3D, tactile/{pad}/pad_pose, when recorded
    world/objects/{object}          Transform3D, scene/objects/{object}/pose
    primitive                       TextLog, the primitive's name whenever it changes

Rerun (``rerun-sdk``) is the optional extra ``[rerun]``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from univtac_data.storage.errors import DatasetError


def require_rerun() -> Any:
    """``import rerun``, or one clear error naming the extra to install."""
    try:
        import rerun
    except ImportError:
        raise DatasetError("writing a Rerun recording needs rerun-sdk: pip install 'univtac-data[rerun]'") from None
    return rerun


def _transform(rr: Any, pose: np.ndarray) -> Any:
    """Our pose (x, y, z, qw, qx, qy, qz) as a Rerun transform (quaternion x, y, z, w)."""
    return rr.Transform3D(translation=pose[:3], quaternion=rr.Quaternion(xyzw=[pose[4], pose[5], pose[6], pose[3]]))


def log_episode_rrd(handle: Any, out: str) -> int:
    """Log the episode open in ``handle`` into the Rerun recording file ``out``; returns the frames logged."""
    rr = require_rerun()
    meta = handle.meta
    rec = rr.RecordingStream("univtac_data", recording_id=meta.episode_id)
    rec.save(out)
    paths = set(handle.paths())
    per_episode = {
        "timestamps": handle.read("timestamps_ns"),
        "primitive": handle.read("scene/primitive"),
        "ee": handle.read("robot/ee_pose"),
    }
    poses = {f"world/objects/{o}": handle.read(f"scene/objects/{o}/pose") for o in meta.objects}
    for pad in meta.pads:
        if f"tactile/{pad}/pad_pose" in paths:
            poses[f"world/pads/{pad}"] = handle.read(f"tactile/{pad}/pad_pose")
        for name in ("normal_force_n", "slip_mm"):
            per_episode[f"tactile/{pad}/{name}"] = handle.read(f"tactile/{pad}/{name}")
    last_primitive = None
    for t in range(meta.n_frames):
        rec.set_time("frame", sequence=t)
        rec.set_time("time", duration=np.timedelta64(int(per_episode["timestamps"][t]), "ns"))
        for pad in meta.pads:
            base = f"tactile/{pad}"
            rec.log(f"{base}/marked", rr.Image(handle.read(f"{base}/marked_rgb", t)))
            rec.log(f"{base}/marked/markers", rr.Points2D(handle.read(f"{base}/markers_px", t), radii=1.5))
            rec.log(f"{base}/depth", rr.DepthImage(handle.read(f"{base}/depth_um", t), meter=1e6))
            for name in ("normal_force_n", "slip_mm"):
                rec.log(f"{base}/{name}", rr.Scalars(float(per_episode[f"{base}/{name}"][t])))
        for camera in meta.cameras:
            base = f"scene/cameras/{camera.name}"
            rec.log(f"cameras/{camera.name}/rgb", rr.Image(handle.read(f"{base}/rgb", t)))
            if camera.depth:
                rec.log(f"cameras/{camera.name}/depth", rr.DepthImage(handle.read(f"{base}/depth_m", t), meter=1.0))
        rec.log("world/ee", _transform(rr, per_episode["ee"][t]))
        for path, pose in poses.items():
            rec.log(path, _transform(rr, pose[t]))
        primitive = int(per_episode["primitive"][t])
        if primitive != last_primitive:
            names = meta.primitive_names
            rec.log("primitive", rr.TextLog(names[primitive] if 0 <= primitive < len(names) else "none"))
            last_primitive = primitive
    rec.flush()
    rec.disconnect()
    return meta.n_frames
