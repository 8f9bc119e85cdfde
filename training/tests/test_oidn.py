"""Hold-filled frames and the OIDN baselines (issue 11, part 1)."""

import os
import sys

import numpy as np
import pytest
import torch

from ssr import evaluate as E
from ssr import oidn as O
from ssr.baselines import HoldBaseline
from ssr.data import DatasetError, read_exr
from ssr.model import TILE_OFFSETS
from ssr.synth import write_dataset



def _have_pyoidn() -> bool:
    try:
        O.import_pyoidn()
    except O.OIDNUnavailable:
        return False
    return True


HAVE_PYOIDN = _have_pyoidn()
needs_oidn = pytest.mark.skipif(not HAVE_PYOIDN, reason=f"pyoidn is not installed ({O.PIP_INSTALL})")
PRED = ["pred.R", "pred.G", "pred.B"]


def _frame(color_hw, mask_hw, h, w):
    """NCHW frame from [H, W] colour (channel c = (c + 1) * value) and mask arrays."""
    v = torch.tensor(color_hw, dtype=torch.float32).view(1, 1, h, w)
    color = torch.cat([v, 2 * v, 3 * v], dim=1)
    mask = torch.tensor(mask_hw, dtype=torch.float32).view(1, 1, h, w)
    return {"color": color * mask, "mask": mask}


def _run_hold(frames):
    model, state, outs = HoldBaseline(), None, []
    for f in frames:
        r = model(f, state)
        state = r["state"]
        outs.append(r["output"])
    return outs


def _check(out, expected):
    e = torch.tensor(expected, dtype=torch.float32)
    torch.testing.assert_close(out[0], torch.stack([e, 2 * e, 3 * e]), rtol=0, atol=0)


def test_hold_fill_hand_made_sequence():
    # 4x2 image = two 2x2 tiles; frame t traces (dx, dy) = [(0,0), (1,1), (1,0), (0,1)][t] in
    # each tile. Sample values: 100 (t + 1) + 10 y + x, except the sample of (3, 0) at t = 2,
    # which is black (0) and must be held as 0 (traced means mask 1, not colour > 0).
    h, w = 2, 4
    frames = []
    for t in range(4):
        dx, dy = TILE_OFFSETS[t]
        mask = np.zeros((h, w))
        mask[dy::2, dx::2] = 1
        val = np.array([[100 * (t + 1) + 10 * y + x for x in range(w)] for y in range(h)], dtype=float)
        if t == 2:
            val[0, 3] = 0.0
        frames.append(_frame(val, mask, h, w))
    outs = _run_hold(frames)
    # t=0: traced (0,0)=100, (2,0)=102; nothing held yet: every pixel takes its tile's sample
    _check(outs[0], [[100, 100, 102, 102], [100, 100, 102, 102]])
    # t=1: traced (1,1)=211, (3,1)=213; (0,0), (2,0) hold 100, 102; the rest take 211 / 213
    _check(outs[1], [[100, 211, 102, 213], [211, 211, 213, 213]])
    # t=2: traced (1,0)=301, (3,0)=0 (black); (0,1), (2,1) never traced: 301 and 0
    _check(outs[2], [[100, 301, 102, 0], [301, 211, 0, 213]])
    # t=3: traced (0,1)=410, (2,1)=412; every pixel now holds its own last sample
    _check(outs[3], [[100, 301, 102, 0], [410, 211, 412, 213]])


def test_hold_fill_partial_tile_and_batch():
    # 3x2 image: the right tile is one column wide. At t=1 its traced pixel (3, 1) is outside
    # the frame, so (2, 1), never traced, takes the mean of this frame's samples in its 3x3
    # neighbourhood: only (1, 1) = 7.
    h, w = 2, 3
    m0 = [[1, 0, 1], [0, 0, 0]]
    m1 = [[0, 0, 0], [0, 1, 0]]
    f0 = _frame([[1, 0, 2], [0, 0, 0]], m0, h, w)
    f1 = _frame([[0, 0, 0], [0, 7, 0]], m1, h, w)
    outs = _run_hold([f0, f1])
    _check(outs[0], [[1, 1, 2], [1, 1, 2]])
    _check(outs[1], [[1, 7, 2], [7, 7, 7]])
    # a batch of two sequences is two independent sequences
    both = [{k: torch.cat([a[k], b[k]]) for k in a} for a, b in ((f0, f1), (f1, f0))]
    ob = _run_hold(both)
    torch.testing.assert_close(ob[1][0], outs[1][0])
    torch.testing.assert_close(ob[0][1], _run_hold([f1])[0][0])


def test_hold_fill_on_synthetic_dataset_beats_input(tmp_path):
    root = write_dataset(str(tmp_path / "d"), {"test": 1}, 5, 16, 12, seed=1)
    out = str(tmp_path / "pred")
    assert E.main(["--data", root, "--out", out, "--device", "cpu", "--models", "input", "hold",
                   "--json", str(tmp_path / "m.json")]) == 0  # fmt: skip
    # frame 3 of the static-pattern sequence: traced pixels are exactly the input's samples
    seq = os.path.join(root, "test", "synthetic_000")
    frame = read_exr(os.path.join(seq, "frame_0003.exr"), ["color.R", "color.G", "color.B", "mask.Y"])
    pred = read_exr(os.path.join(out, "hold", "test", "synthetic_000", "frame_0003.exr"), PRED)
    traced = frame[..., 3] > 0.5
    np.testing.assert_array_equal(pred[traced], frame[..., :3][traced])
    assert (pred[~traced] > 0).all()  # every untraced pixel holds a (positive) earlier sample


def _constant_frames(t_count=4, h=64, w=64, seed=0):
    """A static camera looking at a constant HDR colour, 1/4-spp samples with mean-1
    log-normal noise, clean albedo/normal, and a 1-spp `full` frame."""
    rng = np.random.default_rng(seed)
    clean = torch.tensor([1.2, 0.6, 0.3]).view(1, 3, 1, 1).expand(1, 3, h, w).contiguous()
    albedo = torch.tensor([0.8, 0.5, 0.4]).view(1, 3, 1, 1).expand(1, 3, h, w).contiguous()
    normal = torch.zeros(1, 3, h, w)
    normal[:, 2] = 1.0
    frames = []
    for t in range(t_count):
        dx, dy = TILE_OFFSETS[t % 4]
        mask = torch.zeros(1, 1, h, w)
        mask[..., dy::2, dx::2] = 1.0
        noise = torch.from_numpy(rng.lognormal(-0.125, 0.5, size=(1, 3, h, w)).astype(np.float32))
        full_noise = torch.from_numpy(rng.lognormal(-0.125, 0.5, size=(1, 3, h, w)).astype(np.float32))
        frames.append({"color": clean * noise * mask, "mask": mask, "albedo": albedo, "normal": normal,
                       "motion": torch.zeros(1, 2, h, w), "full": clean * full_noise})  # fmt: skip
    return frames, clean


def _l1(a, b):
    return float((a - b).abs().mean())


@needs_oidn
def test_oidn_a_denoises_hold_filled_constant_image():
    frames, clean = _constant_frames()
    model, state = O.oidn_a(), None
    for f in frames:
        r = model(f, state)
        state = r["state"]
    out, inp = r["output"], r["input"]
    assert out.shape == clean.shape and torch.isfinite(out).all()
    # the input is the hold-filled frame: by frame 3 every pixel holds its own sample
    torch.testing.assert_close(inp, HoldBaseline().run_sequence(frames)[-1]["output"])
    err_in, err_out = _l1(inp, clean), _l1(out, clean)
    assert err_out < 0.2 * err_in, (err_in, err_out)
    rel = (out.mean(dim=(2, 3)) / clean.mean(dim=(2, 3)) - 1).abs()
    assert float(rel.max()) < 0.03, rel  # brightness preserved per channel within 3 %


@needs_oidn
def test_oidn_b_denoises_full_frame():
    frames, clean = _constant_frames(t_count=1, seed=1)
    r = O.oidn_b()(frames[0])
    torch.testing.assert_close(r["input"], frames[0]["full"])
    err_in, err_out = _l1(frames[0]["full"], clean), _l1(r["output"], clean)
    assert err_out < 0.2 * err_in, (err_in, err_out)
    rel = (r["output"].mean(dim=(2, 3)) / clean.mean(dim=(2, 3)) - 1).abs()
    assert float(rel.max()) < 0.03, rel
    with pytest.raises(KeyError, match="full"):
        O.oidn_b()({k: v for k, v in frames[0].items() if k != "full"})


@needs_oidn
def test_oidn_rows_in_evaluate(tmp_path, capsys):
    root = write_dataset(str(tmp_path / "d"), {"test": 1}, 5, 32, 32, seed=2, full=True)
    out = str(tmp_path / "pred")
    js = str(tmp_path / "m.json")
    assert E.main(["--data", root, "--out", out, "--device", "cpu", "--json", js,
                   "--models", "hold", "oidn-a", "oidn-b"]) == 0  # fmt: skip
    text = capsys.readouterr().out
    assert any(line.startswith("oidn-b") and line.count(" / ") == 4 for line in text.splitlines())
    s = __import__("json").load(open(js))["summary"]
    assert s["oidn-a"]["mean"]["psnr"] > s["hold"]["mean"]["psnr"] + 3
    assert s["oidn-b"]["mean"]["psnr"] > s["oidn-a"]["mean"]["psnr"]
    assert s["oidn-a"]["mean"]["temporal"] < s["hold"]["mean"]["temporal"]
    info = __import__("json").load(open(os.path.join(out, "oidn-a", "test", "synthetic_000", "prediction.json")))
    assert info["format"] == "non-learned-oidn-a" and info["oidn"]["oidn"].startswith("2.5")
    assert info["oidn"]["device"] == "cpu" and info["oidn"]["hdr"] and info["oidn"]["cleanAux"]
    pred = read_exr(os.path.join(out, "oidn-b", "test", "synthetic_000", "frame_0004.exr"), PRED)
    assert pred.shape == (32, 32, 3) and np.isfinite(pred).all()


def test_oidn_b_missing_channels(tmp_path, capsys):
    root = write_dataset(str(tmp_path / "d"), {"test": 1}, 2, 8, 8, seed=0)
    f0 = os.path.join(root, "test", "synthetic_000", "frame_0000.exr")
    with pytest.raises(DatasetError) as err:
        O.read_full(f0)
    assert f0 in str(err.value) and "'full.R', 'full.G', 'full.B'" in str(err.value)
    assert O.main(["--has-full", f0]) == 1
    assert "missing full.R full.G full.B" in capsys.readouterr().err
    full = write_dataset(str(tmp_path / "f"), {"test": 1}, 2, 8, 8, seed=0, full=True)
    assert O.main(["--has-full", os.path.join(full, "test", "synthetic_000", "frame_0001.exr")]) == 0
    assert O.read_full(os.path.join(full, "test", "synthetic_000", "frame_0001.exr"))["full"].shape == (3, 8, 8)
    if HAVE_PYOIDN:  # evaluate fails before running anything, naming the file and channels
        assert E.main(["--data", root, "--out", str(tmp_path / "p"), "--device", "cpu", "--models", "hold", "oidn-b"]) == 1
        msg = capsys.readouterr().err
        assert f0 in msg and "full.R" in msg and "2 of 2 frames" in msg
        assert not os.path.exists(str(tmp_path / "p" / "hold"))


def test_missing_pyoidn_is_a_clear_error(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "pyoidn", None)  # `import pyoidn` raises ImportError
    for make in (O.oidn_a, O.oidn_b):
        with pytest.raises(O.OIDNUnavailable) as err:
            make()
        assert "`pyoidn`" in str(err.value) and "pip install pyoidn==" in str(err.value)
    root = write_dataset(str(tmp_path / "d"), {"test": 1}, 2, 8, 8, seed=0)
    assert E.main(["--data", root, "--device", "cpu", "--models", "oidn-a"]) == 1
    msg = capsys.readouterr().err
    assert "pyoidn" in msg and "pip install" in msg


@needs_oidn
def test_oidn_footprint_rows_take_the_footprint_albedo(tmp_path, capsys):
    """oidn-a-footprint / oidn-b-footprint are OIDN with the frame's footprint albedo as its
    albedo image: exactly oidn-a / oidn-b on the frame with its albedo replaced by it; in
    evaluate they read the channels, and a dataset without them fails first, naming them."""
    frames, _ = _constant_frames(t_count=1, seed=3)
    f = dict(frames[0])
    g = torch.Generator().manual_seed(5)
    f["albedo_footprint"] = torch.rand(f["albedo"].shape, generator=g)
    swapped = {**f, "albedo": f["albedo_footprint"]}
    for name, plain in (("oidn-a-footprint", O.oidn_a), ("oidn-b-footprint", O.oidn_b)):
        fp = O.OIDN_MODELS[name]()
        assert fp.NAME == name and fp.info()["oidn"]["aux"][0] == "albedo_footprint"
        got = fp(f)["output"]
        assert torch.equal(got, plain()(swapped)["output"])
        assert not torch.equal(got, plain()(f)["output"])
    # two sequences, with and without metrics: every sequence's frames get the buffers
    root = write_dataset(str(tmp_path / "d"), {"test": 2}, 3, 16, 16, seed=2, full=True, background=True)
    for extra in ([], ["--no-metrics"]):
        assert E.main(["--data", root, "--out", str(tmp_path / "p"), "--device", "cpu",
                       "--models", "oidn-a-footprint", "oidn-b-footprint", *extra]) == 0  # fmt: skip
    bare = write_dataset(str(tmp_path / "b"), {"test": 1}, 2, 8, 8, seed=0, full=True)
    capsys.readouterr()
    assert E.main(["--data", bare, "--out", str(tmp_path / "q"), "--device", "cpu", "--models", "oidn-b-footprint"]) == 1
    msg = capsys.readouterr().err
    assert "frame_0000.exr" in msg and "albedo_footprint.R" in msg and "2 of 2 frames" in msg


def _silhouette_brightness(name: str, frames: int = 8) -> float:
    """Mean over the silhouette pixels (0 < coverage < 1) of OIDN row `name`'s output,
    composited as evaluate.py does (the row's config folds the frame, the output pass adds
    the background), against the reference's, on the silhouette frames of test_escaped
    (sky and surface drawn from the footprint's definition, not from any renderer)."""
    from test_escaped import silhouette_frame

    from ssr.model import fold_emission, mean_correction_of, output_pass

    model = O.OIDN_MODELS[name]()
    cfg = getattr(model, "cfg", None)
    gen = torch.Generator().manual_seed(7)
    state, got, want = None, 0.0, 0.0
    for t in range(frames):
        f = {k: v.float() for k, v in silhouette_frame(gen, 64, 64, t).items()}
        f["albedo_footprint"] = torch.full_like(f["color"], 0.5)
        f["normal"] = torch.zeros_like(f["color"])
        f["normal"][:, 2] = 1.0
        fb = fold_emission(f, cfg)
        r = model(fb, state)
        state = r["state"]
        out = r["output"] if name == "oidn-a-footprint" else output_pass(r["output"], fb, mean_correction_of(cfg))
        if name == "oidn-a-footprint":  # the `+ background` row: background_probe's composite, unfolded input
            out = f["background"] + (1 - f["coverage"]) * out
        if t >= 4:  # every pixel traced at least once
            rim = ((f["coverage"] > 0) & (f["coverage"] < 1)).expand_as(out)
            got += out[rim].sum().item()
            want += f["reference"][rim].sum().item()
    return got / want


@needs_oidn
def test_oidn_escaped_row_leaves_the_sky_of_silhouettes_to_the_background():
    """oidn-a-footprint-escaped is fed what an SSR model of escaped = "background" is fed and
    composited as the engine composites: on silhouettes against a bright sky it keeps their
    brightness, where the `+ background` composite of the plain row counts the sky twice."""
    fair = _silhouette_brightness("oidn-a-footprint-escaped")
    doubled = _silhouette_brightness("oidn-a-footprint")
    assert abs(fair - 1.0) < 0.1, fair
    assert doubled > 1.2, doubled
    m = O.OIDN_MODELS["oidn-a-footprint-escaped"]()
    assert m.NAME == "oidn-a-footprint-escaped" and m.info()["oidn"]["escaped"] == "background"
    assert {"escaped", "background", "coverage", "albedo_footprint"} <= set(m.extra_buffers)
    with pytest.raises(ValueError, match="hold-filled"):
        O.OIDNBaseline("full", "footprint", escaped=True)


@needs_oidn
def test_oidn_escaped_row_in_evaluate_reads_the_escapes_or_names_them(tmp_path, capsys):
    root = write_dataset(str(tmp_path / "d"), {"test": 1}, 3, 16, 16, seed=2, background=True, emission=True)
    js = str(tmp_path / "m.json")
    assert E.main(["--data", root, "--out", str(tmp_path / "p"), "--device", "cpu", "--json", js,
                   "--models", "oidn-a-footprint-escaped"]) == 0  # fmt: skip
    pred = read_exr(os.path.join(str(tmp_path / "p"), "oidn-a-footprint-escaped", "test", "synthetic_000", "frame_0002.exr"), PRED)
    assert np.isfinite(pred).all()
    # the wholly sky rows (coverage 1) are the background exactly: the composite is the engine's
    ref = read_exr(os.path.join(root, "test", "synthetic_000", "frame_0002.exr"), ["background.R", "background.G", "background.B"])
    np.testing.assert_allclose(pred[:4], ref[:4], rtol=1e-6, atol=0)
    bare = write_dataset(str(tmp_path / "b"), {"test": 1}, 2, 8, 8, seed=0, background=True)  # no `escaped`
    capsys.readouterr()
    assert E.main(["--data", bare, "--out", str(tmp_path / "q"), "--device", "cpu", "--models", "oidn-a-footprint-escaped"]) == 1
    msg = capsys.readouterr().err
    assert "escaped.Y" in msg and "frame_0000.exr" in msg
