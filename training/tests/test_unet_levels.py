"""A fourth U-Net level (config `enc` with four widths, PyTorch only): shapes, cost, and
growing a 3-level model into one that computes the same (model.grow_unet, `--init`)."""
import pytest
import torch

from ssr import model as M
from ssr import train as T
from ssr.baselines import export_model
from ssr.export import load_weights
from ssr.flops import measured_flops_per_pixel
from ssr.synth import make_sequence

DEEP = {"enc": [16, 32, 28, 24]}


def frames(n=3, size=32, seed=5):
    return [{k: torch.from_numpy(v).unsqueeze(0) for k, v in f.items() if k != "reference"} for f in make_sequence(size, size, n, seed=seed)]


def run(model, seq):
    state, outs = None, []
    for f in seq:
        r = model(f, state)
        state = r["state"]
        outs.append(r)
    return outs


def test_the_fourth_level_runs_at_an_eighth_and_needs_multiples_of_eight():
    torch.manual_seed(0)
    m = M.SSRModel(M.SSRConfig.from_dict({**M.SSRConfig().to_dict(), **DEEP})).eval()
    assert m.pad_multiple == 8 and M.SSRModel().pad_multiple == 4
    with torch.no_grad():
        r = run(m, frames())[-1]
    assert r["enc4"].shape == (1, 24, 4, 4) and r["i4"].shape == (1, 3, 4, 4)
    assert r["output"].shape == (1, 3, 32, 32) and torch.isfinite(r["output"]).all()


def test_its_cost_is_within_the_budget_and_counted_as_measured():
    cfg = M.SSRConfig.from_dict({**M.SSRConfig().to_dict(), **DEEP})
    total, layers = M.flops_per_pixel(cfg)
    base, _ = M.flops_per_pixel(M.SSRConfig())
    names = [n for n, _ in layers]
    assert names.index("unet.enc4.0") > names.index("unet.enc3.2") and names.index("unet.dec4.2") < names.index("unet.dec3.0")
    # the level's four convs at 1/64 of the pixels, and dec3 reading 3 more channels at 1/16
    extra = 18 * ((28 + 3) * 24 + 24 * 24 + (24 + 3) * 24 + 24 * 3) / 64 + 18 * 3 * 28 / 16
    assert total == pytest.approx(base + extra) and total <= 50_000
    torch.manual_seed(0)
    assert measured_flops_per_pixel(M.SSRModel(cfg), 64, 64) == pytest.approx(total)


def test_two_or_five_levels_are_refused():
    for enc in ([16, 32], [16, 32, 28, 24, 20]):
        with pytest.raises(ValueError, match="`enc` must hold 3 widths"):
            M.SSRConfig.from_dict({**M.SSRConfig().to_dict(), "enc": enc})


def test_a_grown_model_computes_what_the_three_level_one_did_and_then_learns_the_level():
    torch.manual_seed(1)
    small = M.SSRModel().eval()
    torch.manual_seed(2)
    deep = M.SSRModel(M.SSRConfig.from_dict({**M.SSRConfig().to_dict(), **DEEP}))
    deep.load_state_dict(M.grow_unet(small.state_dict(), deep))
    deep.eval()
    seq = frames()
    with torch.no_grad():
        a, b = run(small, seq), run(deep, seq)
    for x, y in zip(a, b):
        # the same sums; a conv over more input channels may add them in another order
        torch.testing.assert_close(y["output"], x["output"], rtol=1e-5, atol=1e-7)
    assert b[-1]["i4"].abs().max() > 0  # the level computes something; dec3 does not read it yet
    # one backward pass reaches dec3's new input channels (and through them, later, the level)
    deep.train()
    loss = run(deep, seq)[-1]["output"].mean()
    loss.backward()
    g = deep.unet.dec3[0].weight.grad
    assert g[:, 28:31].abs().sum() > 0
    with pytest.raises(ValueError, match="no fourth"):
        M.grow_unet(small.state_dict(), small)


def test_init_grows_three_level_weights_and_refuses_the_reverse(dataset, tmp_path, capsys):
    torch.manual_seed(3)
    small = M.SSRModel()
    path = str(tmp_path / "small.safetensors")
    export_model(small, path, {"test": True})
    deep = M.SSRModel(M.SSRConfig.from_dict({**M.SSRConfig().to_dict(), **DEEP}))
    T.load_init(deep, path, "ssr")
    deep.eval()
    small.eval()
    with torch.no_grad():
        a, b = run(small, frames()), run(deep, frames())
    torch.testing.assert_close(b[-1]["output"], a[-1]["output"], rtol=1e-5, atol=1e-7)
    deep_path = str(tmp_path / "deep.safetensors")
    export_model(deep, deep_path, {"test": True})
    loaded, _ = load_weights(deep_path)
    assert loaded.cfg.enc == (16, 32, 28, 24)
    with pytest.raises(T.CheckpointError, match="differs"):
        T.load_init(M.SSRModel(), deep_path, "ssr")
    other = M.SSRModel(M.SSRConfig.from_dict({**M.SSRConfig().to_dict(), "enc": [16, 32, 20, 24]}))
    with pytest.raises(T.CheckpointError, match="differs"):
        T.load_init(other, path, "ssr")


def test_training_a_deep_model_needs_crops_of_eight(dataset, tmp_path):
    common = ["--data", dataset, "--iters", "1", "--batch", "2", "--workers", "0", "--val-every", "0", "--device", "cpu",
              "--model-config", '{"enc": [16, 32, 28, 24]}']  # fmt: skip
    with pytest.raises(SystemExit, match="multiple of 8"):
        T.train([*common, "--out", str(tmp_path / "a"), "--crop", "20"])
    res = T.train([*common, "--out", str(tmp_path / "b"), "--crop", "16"])
    loaded, _ = load_weights(res["weights"])
    assert loaded.cfg.enc == (16, 32, 28, 24)
