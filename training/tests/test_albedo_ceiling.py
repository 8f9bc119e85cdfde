"""ssr.albedo_ceiling: the box filter, an analytic half-and-half pixel, and the CLI over a
tiny dataset written with the dataset's own writer."""

import json
import os

import numpy as np
import pytest

from ssr import albedo_ceiling as ac
from ssr.data import DatasetError, frame_name, write_exr
from ssr.metrics import psnr
from ssr.model import ALBEDO_EPS


def test_footprint_is_the_box_filter_and_checks_the_ratio():
    fine = np.arange(4 * 6 * 1, dtype=np.float64).reshape(4, 6, 1)
    got = ac.footprint(fine, 3, 2)
    assert got.shape == (2, 3, 1)
    assert got[0, 0, 0] == np.mean([0, 1, 6, 7])
    assert got[1, 2, 0] == np.mean([16, 17, 22, 23])
    with pytest.raises(DatasetError):
        ac.footprint(fine, 4, 2)  # 6 is not a multiple of 4
    with pytest.raises(DatasetError):
        ac.footprint(np.zeros((4, 9, 1)), 3, 2)  # x3 across, x2 down


def test_a_pixel_half_red_half_white_is_the_analytic_case():
    # Irradiance 1 everywhere; one pixel's footprint is half a red wall, half a white one,
    # its centre on the red: the reference is the mean of the two, the centre remodulation
    # gives red alone. Every other pixel is plain white.
    h, w = 4, 4
    red, white = np.array([0.6, 0.05, 0.05]), np.array([0.8, 0.8, 0.8])
    centre = np.tile(white, (h, w, 1))
    foot = centre.copy()
    centre[1, 2] = red
    foot[1, 2] = (red + white) / 2
    reference = foot * 1.0
    r = ac.frame_ceiling(reference, centre, foot)
    assert r["mixed"] == pytest.approx(1 / 16)
    want = reference.copy()
    want[1, 2] = (reference[1, 2] / (foot[1, 2] + ALBEDO_EPS)) * (red + ALBEDO_EPS)
    assert r["psnr"] == pytest.approx(psnr(want, reference))
    assert np.isfinite(r["psnr"]) and r["psnr"] < 40
    # Where centre and footprint agree, the ceiling is perfect.
    assert ac.frame_ceiling(reference, foot, foot)["psnr"] == float("inf")


def _sequence(root, name, w, h, albedo, reference=None, albedo_footprint=None):
    d = os.path.join(root, "val", name)
    os.makedirs(d)
    json.dump(
        {
            "scene": name,
            "split": "val",
            "sequence": 0,
            "frames": 1,
            "width": w,
            "height": h,
            "spp": 1,
            "seed": 0,
            "camera_path": "static",
        },
        open(os.path.join(d, "sequence.json"), "w"),
    )
    bufs = {"albedo": albedo.transpose(2, 0, 1)}
    if reference is not None:
        bufs["reference"] = reference.transpose(2, 0, 1)
    if albedo_footprint is not None:
        bufs["albedo_footprint"] = albedo_footprint.transpose(2, 0, 1)
    write_exr(os.path.join(d, frame_name(0)), bufs, {"albedo_footprint": ("R", "G", "B")})


def test_cli_scores_the_sequences_that_have_a_fine_render(tmp_path, capsys):
    data, fine = str(tmp_path / "ds"), str(tmp_path / "fine")
    rng = np.random.default_rng(3)
    fine_albedo = rng.uniform(0.1, 0.9, (8, 8, 3))
    foot = ac.footprint(fine_albedo, 4, 4)
    centre = fine_albedo[::2, ::2]  # one of each pixel's four points
    _sequence(data, "a_val_000", 4, 4, centre, foot * 0.7)
    _sequence(data, "b_val_000", 4, 4, centre, foot * 0.7)  # no fine render: left out
    _sequence(fine, "a_val_000", 8, 8, fine_albedo)
    assert ac.main(["--data", data, "--fine", fine]) == 0
    out = capsys.readouterr().out
    want = psnr((foot * 0.7) / (foot + ALBEDO_EPS) * (centre + ALBEDO_EPS), foot * 0.7)
    assert f"| a_val_000 |" in out and f"{want:.2f}" in out
    assert "b_val_000" not in out and "mean of 1" in out
    # No fine render at all: a named error.
    assert ac.main(["--data", data, "--fine", str(tmp_path / "none")]) == 2
    assert "no sequence" in capsys.readouterr().err


def test_cli_reads_the_frames_own_footprint_albedo(tmp_path, capsys):
    """Without --fine, the footprint albedo is the frames' `albedo_footprint` channels (as
    `subpixel dataset --background N` writes them): the same figure as the fine render
    gives for the same box filter; a frame without the channels is a named error."""
    data = str(tmp_path / "ds")
    rng = np.random.default_rng(4)
    fine_albedo = rng.uniform(0.1, 0.9, (8, 8, 3))
    foot = ac.footprint(fine_albedo, 4, 4)
    centre = fine_albedo[::2, ::2]
    _sequence(data, "a_val_000", 4, 4, centre, foot * 0.7, albedo_footprint=foot)
    assert ac.main(["--data", data]) == 0
    want = psnr((foot * 0.7) / (foot + ALBEDO_EPS) * (centre + ALBEDO_EPS), foot * 0.7)
    assert f"{want:.2f}" in capsys.readouterr().out
    _sequence(data, "b_val_000", 4, 4, centre, foot * 0.7)
    assert ac.main(["--data", data]) == 2
    err = capsys.readouterr().err
    assert "b_val_000" in err and "albedo_footprint.R" in err
