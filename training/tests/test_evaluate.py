import json
import os
import sys

import numpy as np
import pytest
import torch

from ssr import evaluate as E
from ssr.baselines import export_model, build_model
from ssr.data import read_exr
from ssr.export import export_random

from conftest import DATASET_FRAMES, DATASET_SIZE

TRAINING = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_model_specs():
    assert E.parse_model_spec("input") == ("input", "input")
    assert E.parse_model_spec("acc=accumulation") == ("acc", "accumulation")
    assert E.parse_model_spec("ssr=a/b.safetensors") == ("ssr", "a/b.safetensors")
    with pytest.raises(ValueError, match="NAME=PATH"):
        E.parse_model_spec("weights.safetensors")


def test_evaluate_writes_predictions_and_table(dataset, tmp_path, capsys):
    ssr = str(tmp_path / "ssr.safetensors")
    export_random(ssr, seed=0)
    torch.manual_seed(0)
    nsrr = str(tmp_path / "nsrr.safetensors")
    export_model(build_model("nsrr", {"enc": [8, 8], "bottleneck": 8, "feat_hidden": 8, "reweight_hidden": 8}), nsrr, {})
    out = str(tmp_path / "pred")
    js = str(tmp_path / "m.json")
    rc = E.main(["--data", dataset, "--split", "test", "--out", out, "--json", js, "--device", "cpu",
                 "--models", "input", "accumulation", f"ssr={ssr}", f"nsrr={nsrr}"])  # fmt: skip
    assert rc == 0
    text = capsys.readouterr().out
    assert "PSNR (dB) / SSIM / temporal error on test" in text
    for name in ("input", "accumulation", "ssr", "nsrr"):
        folder = os.path.join(out, name, "test", "synthetic_000")
        files = sorted(f for f in os.listdir(folder) if f.endswith(".exr"))
        assert files == [f"frame_{i:04d}.exr" for i in range(DATASET_FRAMES)]
        assert json.load(open(os.path.join(folder, "sequence.json")))["split"] == "test"
        assert json.load(open(os.path.join(folder, "prediction.json")))["model"] == name
        arr = read_exr(os.path.join(folder, "frame_0003.exr"), ["pred.R", "pred.G", "pred.B"])
        assert arr.shape == (DATASET_SIZE, DATASET_SIZE, 3) and np.isfinite(arr).all()
        assert any(line.startswith(name) for line in text.splitlines())
    # the input model's prediction is the input colour
    ref = read_exr(os.path.join(dataset, "test", "synthetic_000", "frame_0003.exr"), ["color.R", "color.G", "color.B"])
    np.testing.assert_array_equal(read_exr(os.path.join(out, "input", "test", "synthetic_000", "frame_0003.exr"), ["pred.R", "pred.G", "pred.B"]), ref)
    m = json.load(open(js))
    assert set(m["summary"]) == {"input", "accumulation", "ssr", "nsrr"}
    acc, inp = m["summary"]["accumulation"]["mean"], m["summary"]["input"]["mean"]
    assert acc["psnr"] > inp["psnr"] + 5 and acc["ssim"] > inp["ssim"]
    assert all(r["frames"] == DATASET_FRAMES for r in m["sequences"])


def test_a_mean_corrected_model_gets_the_engines_whole_output_pass(tmp_path):
    from ssr.data import SequenceDataset, pad_frame
    from ssr.model import MeanCorrection, composite_background, fold_emission
    from ssr.synth import write_dataset

    root = write_dataset(str(tmp_path / "ds"), {"test": 1}, frames=4, width=32, height=32, seed=4, background=True, emission=True)
    torch.manual_seed(5)
    model = build_model("ssr", {"mean_correction": "tiles16", "emission": "background", "albedo": "footprint"})
    path = str(tmp_path / "ssr.safetensors")
    export_model(model, path, {})
    out = str(tmp_path / "pred")
    assert E.main(["--data", root, "--split", "test", "--out", out, "--device", "cpu", "--models", f"ssr={path}"]) == 0
    # expected: the model's output through MeanCorrection over 16-pixel tiles from frame 0
    model.eval()
    ds = SequenceDataset(root, "test", window=1, crop=None, flips=False, extra=model.extra_buffers + ("background", "coverage"))
    mc, state = MeanCorrection(16), None
    seq = ds.sequences[0]
    with torch.no_grad():
        for t in range(seq.frames):
            fb = fold_emission({k: v.unsqueeze(0) for k, v in ds.full_frame(0, t).items()}, model.cfg)
            padded, (h, w) = pad_frame(fb, 4)
            r = model(padded, state)
            state = r["state"]
            y = r["output"][:, :, :h, :w]
            want, plain = mc(y, fb)[0].permute(1, 2, 0).numpy(), composite_background(y, fb)[0].permute(1, 2, 0).numpy()
            got = read_exr(os.path.join(out, "ssr", "test", seq.name, f"frame_{t:04d}.exr"), ["pred.R", "pred.G", "pred.B"])
            np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-7)
    assert np.abs(want - plain).max() > 1e-4  # the correction changed the output


def test_evaluate_errors(dataset, tmp_path, capsys):
    assert E.main(["--data", dataset, "--models", f"x={tmp_path / 'none.safetensors'}", "--device", "cpu"]) == 1
    assert "none.safetensors" in capsys.readouterr().err
    assert E.main(["--data", str(tmp_path), "--models", "input", "--device", "cpu"]) == 1
    assert "no such split" in capsys.readouterr().err


def test_bench_torch_cpu(tmp_path, capsys):
    sys.path.insert(0, TRAINING)
    import bench_torch

    w = str(tmp_path / "w.safetensors")
    export_random(w, seed=0)
    js = str(tmp_path / "b.json")
    rc = bench_torch.main(["--weights", w, "--width", "32", "--height", "30", "--frames", "2", "--warmup", "1",
                           "--device", "cpu", "--modes", "eager,fp16", "--json", js])  # fmt: skip
    assert rc == 0
    text = capsys.readouterr().out
    lines = text.splitlines()
    assert any(l.startswith("eager fp32") and " tfa " in l for l in lines)
    assert any(l.split()[:1] == ["unet"] for l in lines) and any(l.split()[:1] == ["total"] for l in lines)
    assert "channels-last fp16 skipped: CUDA only" in text
    res = json.load(open(js))
    assert res["padded"] == [32, 32] and len(res["results"]) == 1
    st = res["results"][0]["stages"]
    assert st["total"]["flops"] == st["tfa"]["flops"] + st["unet"]["flops"]
    assert st["total"]["flops"] == pytest.approx(49279.5 * 32 * 32)
    assert st["total"]["median_ms"] > 0 and st["total"]["gflop_per_s"] > 0
