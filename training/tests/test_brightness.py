import numpy as np
import pytest

from ssr.brightness import main, region_masks, sequence_sums
from ssr.data import DatasetError, write_exr


def test_regions_partition_the_frame():
    met = np.array([[0.0, 1.0], [0.6, 0.2]])
    cov = np.array([[1.0, 1.0], [0.0, 0.0]])
    m = region_masks(met, cov)
    assert m["environment"].tolist() == [[True, True], [False, False]]
    assert m["metal"].tolist() == [[False, False], [True, False]]
    assert m["non-metal"].tolist() == [[False, False], [False, True]]
    assert "environment" not in region_masks(met, None)
    assert region_masks(met, None)["metal"].tolist() == [[False, True], [True, False]]
    # --silhouette: 0 < coverage < 1 apart, still a partition
    cov = np.array([[1.0, 0.4], [0.7, 0.0]])
    m = region_masks(met, cov, silhouette=True)
    assert m["silhouette"].tolist() == [[False, True], [True, False]]
    assert m["environment"].tolist() == [[True, False], [False, False]]
    assert m["metal"].tolist() == [[False, False], [False, False]]
    assert m["non-metal"].tolist() == [[False, False], [False, True]]
    assert sum(v.astype(int) for v in m.values()).tolist() == [[1, 1], [1, 1]]
    assert "silhouette" not in region_masks(met, cov)


def _frame(path, ref, met, cov):
    write_exr(path, {"reference": ref.transpose(2, 0, 1), "metallic": met, "coverage": cov}, {"coverage": ["Y"]})


def _pred(path, p):
    write_exr(path, {"pred": p.transpose(2, 0, 1)}, {"pred": ["R", "G", "B"]})


def test_ratios_recover_known_per_region_scales(tmp_path, capsys):
    rng = np.random.default_rng(1)
    h, w = 6, 8
    met = np.zeros((h, w), np.float32)
    met[:, :3] = 1.0
    cov = np.zeros((h, w), np.float32)
    cov[:2, 3:] = 1.0
    masks = region_masks(met, cov)
    scale = {"metal": np.array([0.5, 0.75, 1.0]), "non-metal": np.array([1.2, 1.0, 1.0]),
             "environment": np.array([1.0, 1.0, 2.0])}
    for i in range(2):
        ref = rng.uniform(0.1, 3.0, (h, w, 3)).astype(np.float32)
        _frame(str(tmp_path / "ds/test/s_000" / f"frame_{i:04d}.exr"), ref, met, cov)
        out = ref.copy()
        for r, m in masks.items():
            out[m] = ref[m] * scale[r]
        _pred(str(tmp_path / "pred/a/test/s_000" / f"frame_{i:04d}.exr"), out)
        _pred(str(tmp_path / "pred/b/test/s_000" / f"frame_{i:04d}.exr"), ref)
    sums = sequence_sums(str(tmp_path / "ds"), "test", "s_000", str(tmp_path / "pred"), ["a", "b"])
    ratios = sums.ratios()
    for r in scale:
        assert np.allclose(ratios["a"][r], scale[r], rtol=1e-5)
        assert np.allclose(ratios["b"][r], 1.0, rtol=1e-5)
    fr = sums.fractions()
    assert np.isclose(fr["metal"], 18 / 48) and np.isclose(fr["environment"], 10 / 48)
    assert np.isclose(sum(fr.values()), 1.0)
    assert main(["--data", str(tmp_path / "ds"), "--pred", str(tmp_path / "pred"), "--methods", "a", "b"]) == 0
    out = capsys.readouterr().out
    assert "metal: 0.50 / 0.75 / 1.00" in out and "environment: 1.00 / 1.00 / 2.00" in out


def test_a_missing_prediction_names_the_file(tmp_path):
    ref = np.ones((4, 4, 3), np.float32)
    _frame(str(tmp_path / "ds/test/s_000/frame_0000.exr"), ref, np.zeros((4, 4), np.float32), np.zeros((4, 4), np.float32))
    with pytest.raises(DatasetError, match="pred/x/test/s_000/frame_0000.exr: missing prediction of `x`"):
        sequence_sums(str(tmp_path / "ds"), "test", "s_000", str(tmp_path / "pred"), ["x"])
    assert main(["--data", str(tmp_path / "ds"), "--pred", str(tmp_path / "pred"), "--methods", "x"]) == 1
