"""Each safety and physics rule against an episode built to break it (and only it, where physics allows)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from factories import make_episode
from test_validate_support import clean_and_broken, failing, refresh_safety, write_dataset

from univtac_data import Episode
from univtac_data.validators import ValidationConfig, validate

T = 4  # frames; frame 0 has no contact, frames 1..3 press both pads


def _episode(n_frames: int = T) -> Episode:
    return make_episode("gelsight_mini", n_frames, "ep1", seed=1)


def _deepest_pixel(ep: Episode, pad: str, frame: int) -> tuple[int, int]:
    depth = ep[f"tactile/{pad}/depth_um"][frame]
    return np.unravel_index(int(depth.argmax()), depth.shape)  # type: ignore[return-value]


def too_deep(ep: Episode) -> None:
    ep["tactile/left/depth_um"][(2, *_deepest_pixel(ep, "left", 2))] = 2000  # 2 mm > safe 1.5 mm


def deeper_than_gel(ep: Episode) -> None:
    ep["tactile/left/depth_um"][(2, *_deepest_pixel(ep, "left", 2))] = 5000  # 5 mm > 4 mm gel


def slips_while_held(ep: Episode) -> None:
    ep["tactile/right/slip_mm"][2] = 5.0


def crushes(ep: Episode) -> None:
    ep["tactile/left/normal_force_n"][2] = 100.0


def pulls(ep: Episode) -> None:
    ep["tactile/left/normal_force_n"][2] = -1.0


def lies_in_summary(ep: Episode) -> None:
    ep.meta.safety = ep.meta.safety.model_copy(update={"max_indentation_mm": ep.meta.safety.max_indentation_mm + 0.5})


def nan_shear(ep: Episode) -> None:
    ep["tactile/left/shear_force_n"][2, 0] = np.nan


def inf_marker(ep: Episode) -> None:
    ep["tactile/right/markers_ref_px"][3, 1] = np.inf


def long_quaternion(ep: Episode) -> None:
    ep["robot/ee_pose"][1, 3] = 1.1


def short_action_quaternion(ep: Episode) -> None:
    ep["robot/action"][1, 3] = 0.5


def teleports(ep: Episode) -> None:
    ep["robot/ee_pose"][2:, 0] += 0.5  # 0.5 m in 1/60 s = 30 m/s


def spins(ep: Episode) -> None:
    ep["robot/ee_pose"][2:, 3:7] = [0.0, 1.0, 0.0, 0.0]  # half a turn in 1/60 s


def repeats_timestamp(ep: Episode) -> None:
    ep["timestamps_ns"][2] = ep["timestamps_ns"][1]


def drops_frame(ep: Episode) -> None:
    ep["timestamps_ns"][3:] += ep["timestamps_ns"][1]  # one interval twice as long


def depth_without_contact(ep: Episode) -> None:
    ep["tactile/left/contact_mask"][2] = False


def force_without_contact(ep: Episode) -> None:
    ep["tactile/left/normal_force_n"][0] = 0.5


def marker_off_image(ep: Episode) -> None:
    ep["tactile/left/markers_px"][1, 0] = (-10.0, 5.0)


def marker_off_grid_at_rest(ep: Episode) -> None:
    ep["tactile/left/markers_px"][0, :, 0] += 2.5  # frame 0: nothing touches; 2.5 px > 2 px at rest


def smudge(ep: Episode) -> None:
    ep["tactile/right/marked_rgb"][2, 0:3, 0:3] = 0  # far from every marker


def wrong_reference(ep: Episode) -> None:
    ep["tactile/left/pure_ref_rgb"][:] //= 2  # not what the untouched gel looks like (frame 0 is untouched)


def energy_injection(ep: Episode) -> None:
    ep["scene/objects/indenter/pose"][2:, 0] += 0.02  # 1.2 m/s kick; the gripper moves at 0.06 m/s


def gripper_in_mm(ep: Episode) -> None:
    ep["robot/gripper_width_m"][:] *= 1000.0


def bad_primitive(ep: Episode) -> None:
    ep["scene/primitive"][1] = 5


CASES: dict[str, tuple[Callable[[Episode], None], set[str]]] = {
    "too_deep": (too_deep, {"safety.max_indentation"}),
    "deeper_than_gel": (deeper_than_gel, {"safety.max_indentation", "physics.depth_range"}),
    "slips_while_held": (slips_while_held, {"safety.slip_while_held"}),
    "crushes": (crushes, {"safety.grasp_force"}),
    "pulls": (pulls, {"safety.grasp_force"}),
    "nan_shear": (nan_shear, {"physics.finite"}),
    "inf_marker_ref": (inf_marker, {"physics.finite"}),
    "long_quaternion": (long_quaternion, {"physics.quaternion_norm"}),
    "short_action_quaternion": (short_action_quaternion, {"physics.quaternion_norm"}),
    "teleports": (teleports, {"physics.pose_continuity"}),
    "spins": (spins, {"physics.pose_continuity"}),
    "repeats_timestamp": (repeats_timestamp, {"physics.timestamps"}),
    "drops_frame": (drops_frame, {"physics.timestamps"}),
    "depth_without_contact": (depth_without_contact, {"physics.contact_consistency"}),
    "force_without_contact": (force_without_contact, {"physics.contact_consistency"}),
    # a marker moved without its dot: both the geometry and the image disagree
    "marker_off_image": (marker_off_image, {"physics.markers_in_image", "physics.marked_pure"}),
    "marker_off_grid_at_rest": (marker_off_grid_at_rest, {"physics.markers_at_rest"}),
    "smudge": (smudge, {"physics.marked_pure"}),
    "wrong_reference": (wrong_reference, {"physics.reference_untouched"}),
    "energy_injection": (energy_injection, {"physics.kinetic_energy"}),
    "gripper_in_mm": (gripper_in_mm, {"schema.units"}),
    "bad_primitive": (bad_primitive, {"schema.primitive_index"}),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_rule_catches_broken_episode(tmp_path, case):
    breaker, expected = CASES[case]
    episode = _episode()
    breaker(episode)
    refresh_safety(episode)
    report = validate(clean_and_broken(tmp_path / "ds", episode))
    assert failing(report, "ep1") == expected
    assert failing(report, "ep0") == set()
    assert report.failed_episodes() == ["ep1"]
    for rule in expected:
        check = report.episodes["ep1"].check(rule)
        assert check.findings and all(f.message for f in check.findings)


def test_summary_that_lies_is_caught(tmp_path):
    episode = _episode()
    lies_in_summary(episode)
    report = validate(clean_and_broken(tmp_path / "ds", episode))
    assert failing(report, "ep1") == {"safety.summary"}
    finding = report.episodes["ep1"].check("safety.summary").findings[0]
    assert finding.field == "meta.safety.max_indentation_mm"


def test_findings_name_frames_values_and_threshold(tmp_path):
    episode = _episode()
    too_deep(episode)
    refresh_safety(episode)
    check = validate(clean_and_broken(tmp_path / "ds", episode)).episodes["ep1"].check("safety.max_indentation")
    assert check.threshold_name == "profile.safe_indentation_mm" and check.threshold == 1.5
    (finding,) = check.findings
    assert finding.field == "tactile/left/depth_um"
    assert finding.frames == [2] and finding.values == [2.0] and finding.n_frames == 1


def test_slip_when_not_held_is_allowed(tmp_path):
    episode = _episode()
    episode["tactile/left/slip_mm"][0] = 5.0  # frame 0: no contact, no force
    refresh_safety(episode)
    report = validate(clean_and_broken(tmp_path / "ds", episode))
    assert report.ok


def test_held_by_force_alone(tmp_path):
    episode = _episode()
    episode["tactile/left/contact_mask"][2] = False  # contact masks say not held, forces say held
    episode["tactile/right/slip_mm"][2] = 5.0
    refresh_safety(episode)
    report = validate(clean_and_broken(tmp_path / "ds", episode), groups=("safety",))
    assert failing(report, "ep1") == {"safety.slip_while_held"}


def test_free_fall_and_pushing_are_not_energy_injection(tmp_path):
    n = 20
    episode = make_episode("gelsight_mini", n, "ep1", seed=1, objects=("ball", "box"))
    t = np.arange(n) / 60.0
    ball = episode["scene/objects/ball/pose"]
    ball[:, 2] = 0.6 - 0.5 * 9.81 * t ** 2  # dropped at rest: 3.1 m/s at the end
    box = episode["scene/objects/box/pose"]
    box[:5] = box[5]  # at rest, then carried along with the gripper
    report = validate(clean_and_broken(tmp_path / "ds", episode))
    assert report.ok, report.episodes["ep1"].failed_checks()
    ball[12:, 2] -= 0.03  # a 1.8 m/s kick on top of the fall
    episode.meta = episode.meta.model_copy(update={"episode_id": "ep2"})
    report = validate(write_dataset(tmp_path / "ds2", [episode]))
    check = report.episodes["ep2"].check("physics.kinetic_energy")
    assert check.status == "fail" and check.findings[0].frames == [12]
    assert check.findings[0].limits and check.findings[0].values[0] > check.findings[0].limits[0]


def test_thresholds_come_from_the_config(tmp_path):
    episode = _episode()
    crushes(episode)
    refresh_safety(episode)
    root = clean_and_broken(tmp_path / "ds", episode)
    assert not validate(root).ok
    assert validate(root, config=ValidationConfig(max_normal_force_n=200.0)).ok


def test_markers_far_outside_the_image_do_not_break_the_image_check(tmp_path):
    episode = _episode()
    episode["tactile/left/markers_px"][1, 0] = (1e30, -1e30)
    report = validate(clean_and_broken(tmp_path / "ds", episode))
    assert "physics.markers_in_image" in failing(report, "ep1")
    assert report.episodes["ep1"].check("physics.marked_pure").status in ("pass", "fail")
    assert not any("could not evaluate" in f.message for c in report.episodes["ep1"].checks for f in c.findings)
