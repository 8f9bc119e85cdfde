import os

import numpy as np

from ssr import background_probe as B
from ssr.data import BUFFERS, SUFFIXES, frame_name, read_exr, write_exr
from ssr.evaluate import PRED_SUFFIXES
from ssr.metrics import psnr, ssim
from ssr.synth import write_dataset

RGB = ["R", "G", "B"]


def test_background_mask_needs_depth_one_and_no_tint():
    depth = np.array([[[1.0], [1.0], [0.5]]])  # [1, 3, 1]
    tint = np.zeros((1, 3, 3))
    tint[0, 1] = [0.2, 0.0, 0.0]  # sky seen through glass: not background
    assert B.background_mask(depth, tint).tolist() == [[True, False, False]]


def test_probe_replaces_background_pixels_with_the_1spp_frame(tmp_path, capsys):
    root = write_dataset(str(tmp_path / "d"), {"test": 1}, 2, 8, 8, seed=1, full=True)
    seq = os.path.join(root, "test", "synthetic_000")
    pred = str(tmp_path / "pred")
    expected = []
    for t in range(2):
        f = os.path.join(seq, frame_name(t))
        names = {b: SUFFIXES[b] for b in BUFFERS}
        names.update(reference=("R", "G", "B"), full=("R", "G", "B"))
        bufs = {b: read_exr(f, [f"{b}.{s}" for s in sfx]).transpose(2, 0, 1) for b, sfx in names.items()}
        bufs["depth"][:, :, :4] = 1.0  # the left half escapes to the environment...
        bufs["transparent"][:, 0, 0] = 0.5  # ...but for one pixel behind glass
        # the background channels: wholly sky in the top half's left quarter, one pixel partly
        bufs["background"] = np.full((3, 8, 8), 0.25 + t, np.float32)
        bufs["coverage"] = np.zeros((1, 8, 8), np.float32)
        bufs["coverage"][:, :4, :2] = 1.0
        bufs["coverage"][:, 0, 0] = 0.5
        sfx = {"full": ("R", "G", "B"), "reference": ("R", "G", "B"), "background": ("R", "G", "B"), "coverage": ("Y",)}
        write_exr(f, bufs, sfx)
        zeros = np.zeros((3, 8, 8), np.float32)
        write_exr(os.path.join(pred, "black", "test", "synthetic_000", frame_name(t)), {"pred": zeros}, PRED_SUFFIXES)
        mixed = zeros.copy()
        mixed[:, :, :4] = bufs["full"][:, :, :4]
        mixed[:, 0, 0] = 0.0
        ref = bufs["reference"]
        # black predictions composited: background + (1 - coverage) * 0 = the background
        from_bg = bufs["background"].copy()
        expected.append((psnr(mixed, ref), ssim(mixed, ref), psnr(zeros, ref), psnr(from_bg, ref)))
    res = B.probe(root, pred, ["black"], None, 8, "test")
    r = res["synthetic"]
    assert abs(r["background"] - 31 / 64) < 1e-9
    e = np.mean(np.array(expected), axis=0)
    assert abs(r["black+bg"][0] - e[0]) < 1e-9 and abs(r["black+bg"][1] - e[1]) < 1e-9
    assert abs(r["black"][0] - e[2]) < 1e-9 and r["black+bg"][0] > r["black"][0]
    r2 = B.probe(root, pred, ["black"], None, 8, "test", source="background")["synthetic"]
    assert abs(r2["background"] - 7 / 64) < 1e-9 and abs(r2["black+bg"][0] - e[3]) < 1e-9
    assert B.main(["--data", root, "--pred", pred, "--methods", "black"]) == 0
    assert "| synthetic | 48% |" in capsys.readouterr().out
    # --write: the predictions composited, background + (1 - coverage) * pred; black ones
    # give the background, ones of 1 give background + 1 - coverage
    assert B.main(["--data", root, "--pred", pred, "--write", "black"]) == 0
    for t in range(2):
        got = read_exr(os.path.join(pred, "black-background", "test", "synthetic_000", frame_name(t)), [f"pred.{c}" for c in RGB])
        assert np.array_equal(got, np.full((8, 8, 3), 0.25 + t, np.float32))
        ones = np.ones((3, 8, 8), np.float32)
        write_exr(os.path.join(pred, "white", "test", "synthetic_000", frame_name(t)), {"pred": ones}, PRED_SUFFIXES)
    assert B.main(["--data", root, "--pred", pred, "--write", "white"]) == 0
    cov = np.zeros((8, 8, 1), np.float32)
    cov[:4, :2] = 1.0
    cov[0, 0] = 0.5
    for t in range(2):
        got = read_exr(os.path.join(pred, "white-background", "test", "synthetic_000", frame_name(t)), [f"pred.{c}" for c in RGB])
        assert np.allclose(got, 0.25 + t + 1.0 - cov, atol=1e-6)
    # a method without predictions: an error naming the missing frame
    assert B.main(["--data", root, "--pred", pred, "--methods", "nope"]) == 1
    err = capsys.readouterr().err
    assert "nope" in err and "missing frame" in err, err
