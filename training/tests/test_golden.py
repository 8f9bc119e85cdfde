import os
import subprocess
import sys

import pytest
import torch
from safetensors import safe_open

from ssr import golden
from ssr.export import load_weights
from ssr.model import TILE_OFFSETS, quarter_mask

TRAINING = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(os.path.dirname(TRAINING), "tests", "data")
H, W = golden.HEIGHT, golden.WIDTH

SHAPES = {
    "color": (H, W, 3),
    "mask": (H, W, 1),
    "albedo": (H, W, 3),
    "normal": (H, W, 3),
    "shadow": (H, W, 3),
    "transparent": (H, W, 3),
    "depth": (H, W, 1),
    "metallic": (H, W, 1),
    "roughness": (H, W, 1),
    "motion": (H, W, 2),
    "a_cur": (H, W, 15),
    "warp_acc": (H, W, 15),
    "warp_valid": (H, W, 1),
    "ref_feat": (H, W, 8),
    "emb_cur": (H, W, 8),
    "emb_prev": (H, W, 8),
    "tfa_weights": (H, W, 4),
    "a_acc": (H, W, 15),
    "warp_out": (H, W, 3),
    "i3": (H // 4, W // 4, 3),
    "i2": (H // 2, W // 2, 3),
    "o": (H, W, 3),
    "output": (H, W, 3),
    "enc1": (H, W, 16),
    "enc2": (H // 2, W // 2, 32),
    "enc3": (H // 4, W // 4, 28),
}
SHAPES_V2 = {**SHAPES, "exposure": (1, 1, 9)}
SHAPES_L4 = {**SHAPES_V2, "enc4": (H // 8, W // 8, 24), "i4": (H // 8, W // 8, 3)}
SETS = {"golden_": SHAPES_V2, "golden_l4_": SHAPES_L4, "golden_v1_": SHAPES}
"""File prefix -> the tensors of its frames (version 2: the default config; with a fourth
U-Net level; version 1: legacy)."""
FILES = [f"{p}{n}.safetensors" for p in SETS for n in ["weights"] + [f"frame{t}" for t in range(3)]]


def _read(path):
    with safe_open(path, framework="pt") as f:
        return {k: f.get_tensor(k) for k in f.keys()}, f.metadata()


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    a = str(tmp_path_factory.mktemp("golden_a"))
    b = str(tmp_path_factory.mktemp("golden_b"))
    golden.generate(a, verbose=False)
    subprocess.run([sys.executable, "-m", "ssr.golden", "--out", b], cwd=TRAINING, check=True, capture_output=True)
    return a, b


def test_reproducible_bytes(generated):
    a, b = generated
    for name in FILES:
        with open(os.path.join(a, name), "rb") as fa, open(os.path.join(b, name), "rb") as fb:
            assert fa.read() == fb.read(), name


def test_sizes_names_shapes(generated):
    a, _ = generated
    for name in FILES:
        assert os.path.getsize(os.path.join(a, name)) < 1 << 20, name
    for prefix, shapes in SETS.items():
        for t in range(3):
            tensors, meta = _read(os.path.join(a, f"{prefix}frame{t}.safetensors"))
            assert {k: tuple(v.shape) for k, v in tensors.items()} == shapes
            assert all(v.dtype == torch.float32 for v in tensors.values())
            assert meta["frame"] == str(t) and meta["width"] == str(W) and meta["height"] == str(H)
            assert meta["weights"] == f"{prefix}weights.safetensors"
            assert meta["version"] == ("1" if prefix == "golden_v1_" else "2")
            assert meta["tile_offset"] == str(list(TILE_OFFSETS[t]))


def test_committed_files_match_generator(generated):
    """tests/data is what the generator writes, to float rounding.

    Not bit for bit: torch's CPU kernels behind randn, uniform_, exp and norm round differently per
    instruction set (scalar, AVX2, AVX-512), so another machine writes weights and inputs that differ
    in the last bits (up to ~2e-6 measured with ATEN_CPU_CAPABILITY=default against avx2), and the
    network's tensors follow. Same-machine runs are byte-identical (test_reproducible_bytes)."""
    a, _ = generated
    for name in FILES:
        path = os.path.join(DATA, name)
        assert os.path.exists(path), f"{path} missing: run `python -m ssr.golden --out ../tests/data` in training/"
        want, want_meta = _read(os.path.join(a, name))
        got, got_meta = _read(path)
        assert got_meta == want_meta, name
        assert sorted(got) == sorted(want), name
        for k in want:
            torch.testing.assert_close(got[k], want[k], rtol=1e-5, atol=1e-5, msg=f"{name}: {k}")


@pytest.mark.parametrize("prefix", list(SETS))
def test_inputs_follow_the_contract(generated, prefix):
    a, _ = generated
    any_invalid = any_zero_motion = False
    for t in range(3):
        d, _ = _read(os.path.join(a, f"{prefix}frame{t}.safetensors"))
        mask = d["mask"]
        assert torch.equal(mask, quarter_mask(H, W, t)[0].permute(1, 2, 0))
        untraced = (mask == 0).expand(H, W, 3)
        assert (d["color"] >= 0).all() and (d["color"][untraced] == 0).all()
        assert d["color"].max() > 1.0  # HDR
        assert (d["shadow"] >= 0).all() and (d["shadow"][untraced] == 0).all()
        assert (d["albedo"] >= 0).all() and (d["albedo"] <= 1).all()
        torch.testing.assert_close(d["normal"].norm(dim=-1), torch.ones(H, W))
        assert (d["depth"] >= 0).all() and (d["depth"] <= 1).all()
        assert (d["transparent"] == 0).any() and (d["transparent"] > 0).any()
        assert torch.isfinite(d["motion"]).all()
        any_zero_motion |= bool((d["motion"] == 0).all(-1).any())
        if t > 0:
            v = d["warp_valid"]
            any_invalid |= bool((v == 0).any())
            assert (v == 1).float().mean() > 0.5
            assert (v[16:20, 0] == 1).all() and (v[16:20, W - 1] == 0).all()  # p.x = 0 valid, p.x = W not
        else:
            assert (d["warp_valid"] == 1).all() and (d["warp_out"] == 0).all()
    assert any_invalid and any_zero_motion


def test_v2_exercises_exposure_and_history_test(generated):
    """The version-2 set moves the exposure (history re-exposed) and rejects history by geometry."""
    a, _ = generated
    s = [_read(os.path.join(a, f"golden_frame{t}.safetensors"))[0]["exposure"][..., :6] for t in range(3)]  # s
    assert ((s[1] / s[0]) > 1.02).all() and ((s[2] / s[1]) > 1.02).all()
    # the output ceiling clamps red (pushed, golden.CEILING_PUSH) on some pixels of every frame
    for t in range(3):
        d, _ = _read(os.path.join(a, f"golden_frame{t}.safetensors"))
        e = d["exposure"][0, 0]
        ceil_red = torch.log1p(e[6] / e[0])  # M_r / s_r
        assert 0.01 < float((d["o"][..., 0] >= ceil_red - 1e-6).float().mean()) < 0.8
        assert float(d["o"][..., 0].max()) <= float(ceil_red) + 1e-6
    d, _ = _read(os.path.join(a, "golden_frame1.safetensors"))
    block = d["warp_valid"][2:10, 18:26]  # the disoccluded block of frame 1 (make_frames)
    assert (block == 0).float().mean() > 0.9


@pytest.mark.parametrize("prefix", list(SETS))
def test_outputs_have_spread(generated, prefix):
    a, _ = generated
    for t in range(3):
        d, _ = _read(os.path.join(a, f"{prefix}frame{t}.safetensors"))
        golden.check_spread(d, t)
        assert (d["output"] == 0).any() and (d["output"] > 0).float().mean() > 0.5
        for k in ("enc1", "enc2", "enc3", "enc4")[: 4 if "enc4" in d else 3]:
            frac = (d[k] == 0).float().mean()
            assert 0.2 < frac < 0.8, (t, k, frac)


@pytest.mark.parametrize("prefix", list(SETS))
def test_files_replay_through_loaded_weights(generated, prefix):
    """What the Rust parity test does: load the weights and the inputs, run, compare."""
    a, _ = generated
    model, meta = load_weights(os.path.join(a, f"{prefix}weights.safetensors"))
    assert meta["provenance"].startswith("random-init")
    assert meta["version"] == ("1" if prefix == "golden_v1_" else "2")
    if prefix == "golden_l4_":
        assert list(model.cfg.enc) == golden.L4_ENC
    state = None
    for t in range(3):
        d, _ = _read(os.path.join(a, f"{prefix}frame{t}.safetensors"))
        frame = {k: d[k].permute(2, 0, 1).unsqueeze(0).contiguous() for k in golden.GOLDEN_INPUTS}
        with torch.no_grad():
            r = model(frame, state)
        state = r["state"]
        for k in golden.golden_names(model.cfg):
            torch.testing.assert_close(golden.hwc(r[k]), d[k], rtol=1e-6, atol=1e-6, msg=f"frame {t}: {k}")


def test_fourth_level_carries_signal(generated):
    """The 4-level set tests its level: I4 varies, and dec3 reads it (dec3's weights on the
    upsampled I4 are not zero, unlike a grown model's), so the engine's I4 path is checked."""
    a, _ = generated
    model, _ = load_weights(os.path.join(a, "golden_l4_weights.safetensors"))
    c3 = golden.L4_ENC[2]
    assert model.unet.dec3[0].weight[:, c3 : c3 + 3].abs().min() > 0
    for t in range(3):
        d, _ = _read(os.path.join(a, f"golden_l4_frame{t}.safetensors"))
        assert d["i4"].std() > 0.01, t
