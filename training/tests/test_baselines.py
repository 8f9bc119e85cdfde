import json

import pytest
import torch

from ssr import losses
from ssr.baselines import (
    AccumulationBaseline,
    InputBaseline,
    NSRRModel,
    RAEModel,
    build_model,
    export_model,
    load_model,
    loss_aux,
)
from ssr.export import WeightsError, export_random, write_safetensors
from ssr.golden import make_frames
from ssr.model import SSRModel

H, W = 16, 20


@pytest.fixture(scope="module")
def seq():
    frames = make_frames(seed=3, height=H, width=W, count=5)
    g = torch.Generator().manual_seed(4)
    for f in frames:
        f["reference"] = torch.rand(1, 3, H, W, generator=g) * 2.0
    return frames


@pytest.mark.parametrize("name", ["rae", "nsrr"])
def test_learned_forward_shapes_and_one_step(name, seq):
    torch.manual_seed(0)
    model = build_model(name)
    batch = [{k: v.repeat(2, 1, 1, 1) for k, v in f.items()} for f in seq]  # batch 2
    results = model.run_sequence(batch)
    assert len(results) == 5
    for r in results:
        assert r["output"].shape == (2, 3, H, W) and r["o"].shape == (2, 3, H, W)
        assert torch.isfinite(r["output"]).all() and (r["output"] >= 0).all()
    loss, parts = losses.total_loss([r["output"] for r in results], [f["reference"] for f in batch], loss_aux(results, batch))
    assert set(parts) == {"l_s", "l_t", "l_e", "l_wt", "l_a", "l_m"} and torch.isfinite(loss)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    loss.backward()
    grads = [p.grad for p in model.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    assert sum(float(g.abs().sum() > 0) for g in grads) == len(grads)  # every parameter is used
    opt.step()
    changed = [k for k, v in model.state_dict().items() if not torch.equal(v, before[k])]
    assert len(changed) == len(before)


def test_rae_is_recurrent_and_nsrr_uses_history(seq):
    torch.manual_seed(0)
    rae = RAEModel()
    with torch.no_grad():
        r1 = rae(seq[1], None)["output"]
        r2 = rae(seq[1], rae(seq[0], None)["state"])["output"]
    assert not torch.allclose(r1, r2)
    nsrr = NSRRModel()
    with torch.no_grad():
        first = nsrr(seq[0], None)
        assert len(first["state"]) == nsrr.cfg.history
        w = first["reweight"]
        assert w.shape == (1, nsrr.cfg.history, H, W) and (w >= 0).all() and (w <= 10).all()
        n2 = nsrr(seq[1], first["state"])["output"]
        assert not torch.allclose(n2, nsrr(seq[1], None)["output"])


def test_input_baseline_is_the_input(seq):
    f = dict(seq[0])
    f["color"] = f["color"].clone()
    f["color"][0, 0, 0, 0] = float("nan")
    out = InputBaseline().run_sequence([f])[0]["output"]
    assert out[0, 0, 0, 0] == 0
    torch.testing.assert_close(out[..., 1:], torch.clamp(f["color"][..., 1:], min=0))


def _static_frames(n, h=8, w=8, value=2.0):
    from ssr.model import quarter_mask

    frames = []
    for t in range(n):
        mask = quarter_mask(h, w, t)
        frames.append(
            {
                "color": torch.full((1, 3, h, w), value) * mask,
                "mask": mask,
                "albedo": torch.full((1, 3, h, w), 0.5),
                "normal": torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, h, w).clone(),
                "shadow": mask.expand(1, 3, h, w).clone(),
                "transparent": torch.zeros(1, 3, h, w),
                "depth": torch.full((1, 1, h, w), 0.5),
                "metallic": torch.zeros(1, 1, h, w),
                "roughness": torch.full((1, 1, h, w), 0.5),
                "motion": torch.zeros(1, 2, h, w),
            }
        )
    return frames


def test_accumulation_static_scene_is_exact_and_rejects_depth_jumps():
    acc = AccumulationBaseline()
    frames = _static_frames(6)
    res = acc.run_sequence(frames)
    # a constant scene: the hole fill and the normalised EMA both reproduce the value
    for r in res:
        torch.testing.assert_close(r["output"], torch.full_like(r["output"], 2.0), atol=1e-5, rtol=1e-5)
    assert (res[0]["valid"] == 0).all() and (res[1]["valid"] == 1).all()
    # a depth jump invalidates the history there; a moved-off-screen history too
    f = dict(frames[1])
    f["depth"] = f["depth"].clone()
    f["depth"][..., :4] = 0.9
    f["motion"] = torch.zeros(1, 2, 8, 8)
    f["motion"][:, 0, 0, :] = 100.0
    r = acc(f, res[0]["state"])
    assert (r["valid"][..., :4] == 0).all() and (r["valid"][..., 1:, 4:] == 1).all() and (r["valid"][..., 0, :] == 0).all()
    # EMA weights: the last sample counts alpha relative to (1 - alpha) for the history
    frames = _static_frames(2)
    frames[1]["color"] = frames[1]["color"] * 2.0  # samples of 4 at frame 1's traced pixels
    r = acc.run_sequence(frames)[1]
    m = frames[1]["mask"][0, 0] > 0
    # the history at frame 1's traced pixels is empty (frame 0 traced other pixels): value 4
    torch.testing.assert_close(r["output"][0, 0][m], torch.full_like(r["output"][0, 0][m], 4.0))
    m0 = frames[0]["mask"][0, 0] > 0  # frame 0's pixels: old sample only, 2
    torch.testing.assert_close(r["output"][0, 0][m0], torch.full_like(r["output"][0, 0][m0], 2.0))


@pytest.mark.parametrize("name", ["rae", "nsrr"])
def test_export_and_load_roundtrip(name, tmp_path, seq):
    torch.manual_seed(1)
    model = build_model(name)
    p = str(tmp_path / f"{name}.safetensors")
    export_model(model, p, {"model": name, "iterations": 1}, {"psnr": 1.0})
    loaded, meta = load_model(p)
    assert meta["format"] == f"subpixel-baseline-{name}" and meta["provenance"]["iterations"] == 1
    assert meta["metrics"] == {"psnr": 1.0} and type(loaded) is type(model)
    for k, v in model.state_dict().items():
        assert torch.equal(v, loaded.state_dict()[k])
    with torch.no_grad():
        torch.testing.assert_close(loaded(seq[0])["output"], model(seq[0])["output"])


def test_load_model_dispatches_and_checks(tmp_path):
    p = str(tmp_path / "ssr.safetensors")
    export_random(p, seed=0)
    m, meta = load_model(p)
    assert isinstance(m, SSRModel) and meta["format"] == "subpixel-ssr"
    # a baseline file with a wrong tensor shape and a missing tensor
    rae = RAEModel()
    t = {k: v.clone() for k, v in rae.state_dict().items()}
    t["out.weight"] = torch.zeros(3, 5, 3, 3)
    del t["in1.0.bias"]
    meta = {"format": "subpixel-baseline-rae", "version": "1", "config": json.dumps(rae.cfg.to_dict()), "provenance": "{}", "metrics": "{}"}
    bad = str(tmp_path / "bad.safetensors")
    write_safetensors(bad, t, meta)
    with pytest.raises(WeightsError, match=r"bad\.safetensors: missing tensor `in1\.0\.bias`.*`out\.weight`: shape \[3, 5, 3, 3\]"):
        load_model(bad)
    meta["format"] = "something-else"
    write_safetensors(bad, dict(rae.state_dict()), meta)
    with pytest.raises(WeightsError, match="format"):
        load_model(bad)


def test_build_model_configs():
    assert build_model("rae", {"enc": [8, 12], "bottleneck": 16}).cfg.enc == (8, 12)
    assert build_model("ssr", {"enc": [8, 8, 8]}).cfg.enc == (8, 8, 8)
    # --model-config '{"version": 1}': the version-1 pipeline (e.g. to resume a version-1 run)
    v1 = build_model("ssr", {"version": 1}).cfg
    assert (v1.version, v1.exposure, v1.remodulation, v1.history) == (1, "none", "accumulated", "screen")
    ablation = build_model("ssr", {"exposure": "none", "ceiling": "none"}).cfg
    assert (ablation.version, ablation.exposure, ablation.history) == (2, "none", "geometry")
    with pytest.raises(ValueError, match="unknown model"):
        build_model("unet")
    with pytest.raises(WeightsError, match="unknown"):
        build_model("nsrr", {"widths": 3})
