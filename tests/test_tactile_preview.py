"""The contact sheet and the ``preview`` command."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest
from factories import make_dataset

from univtac_data.cli import preview
from univtac_data.generators.tactile import contact_sheet, demo_gap, simulate_frame
from univtac_data.schema.sensors import get_sensor
from univtac_data.storage.errors import DatasetError


def parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="univtac-data")
    preview.add_parser(parser.add_subparsers(dest="command"))
    return parser.parse_args(["preview", *argv])


def is_png(path: Path) -> bool:
    return path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_contact_sheet_of_frames(tmp_path: Path) -> None:
    profile = get_sensor("xense_ws")
    frames = [simulate_frame(profile, demo_gap(profile, "sphere", d)) for d in (0.1, 0.3)]
    out = contact_sheet(frames, tmp_path / "sheet.png", title="xense")
    assert is_png(out)


def test_preview_demo(tmp_path: Path) -> None:
    out = tmp_path / "demo.png"
    assert preview.run(parse(["--sensor", "gelsight_mini", "--demo", "cross", "--frames", "2", "--out", str(out)])) == 0
    assert is_png(out)


@pytest.mark.parametrize("storage", ["hdf5", "zarr"])
def test_preview_dataset(tmp_path: Path, storage: str) -> None:
    root = make_dataset(tmp_path / "ds", storage=storage, n_episodes=2)
    out = tmp_path / "ep.png"
    args = parse([str(root), "--out", str(out), "--episode", "ep1", "--frames", "3", "--pad", "right"])
    assert preview.run(args) == 0
    assert is_png(out)


def test_a_contact_sheet_interrupted_mid_write_leaves_no_file(tmp_path: Path, monkeypatch) -> None:
    """The PNG goes to a temporary name and is renamed when whole: a write cut short leaves neither a half PNG
    nor the temporary file; a folder that does not exist yet is made, as before."""
    import matplotlib.figure

    root = make_dataset(tmp_path / "ds", n_episodes=1)
    out = tmp_path / "new" / "sheet.png"

    def cut_short(self, path, **kwargs):
        Path(path).write_bytes(b"\x89PNG\r\n\x1a\n half")
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(matplotlib.figure.Figure, "savefig", cut_short)
        with pytest.raises(KeyboardInterrupt):
            preview.run(parse([str(root), "--out", str(out), "--frames", "2"]))
    assert list((tmp_path / "new").iterdir()) == []
    assert preview.run(parse([str(root), "--out", str(out), "--frames", "2"])) == 0
    assert is_png(out) and sorted(p.name for p in out.parent.iterdir()) == ["sheet.png"]


def test_preview_errors_name_the_input(tmp_path: Path) -> None:
    root = make_dataset(tmp_path / "ds", n_episodes=1)
    out = str(tmp_path / "x.png")
    with pytest.raises(DatasetError, match="missing"):
        preview.run(parse([str(tmp_path / "missing"), "--out", out]))
    with pytest.raises(DatasetError, match="ep9"):
        preview.run(parse([str(root), "--episode", "ep9", "--out", out]))
    with pytest.raises(DatasetError, match="nosuch"):
        preview.run(parse(["--sensor", "nosuch", "--demo", "sphere", "--out", out]))
    with pytest.raises(DatasetError, match="blob"):
        preview.run(parse(["--sensor", "gf225", "--demo", "blob", "--out", out]))
    with pytest.raises(DatasetError, match="PATH"):
        preview.run(parse(["--out", out]))
    for depth in ("nan", "0", "-1", "2.5"):  # NaN was a traceback; -1 and deeper than the gel drew a sheet
        with pytest.raises(DatasetError, match=rf"--depth must be above 0 .* 2 mm \(got {depth.replace('.', '[.]')}"):
            preview.run(parse(["--sensor", "gf225", "--demo", "sphere", "--depth", depth, "--out", out]))
    assert not Path(out).exists()
