import json
import os
import subprocess
import sys

import pytest
import torch
from safetensors import safe_open

from ssr.export import (
    FORMAT,
    RANDOM_PROVENANCE,
    WeightsError,
    export_random,
    export_weights,
    load_weights,
    random_model,
    safetensors_bytes,
)
from ssr.model import SSRConfig

TRAINING = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _outputs(model, frames):
    with torch.no_grad():
        return [r["output"] for r in model.run_sequence(frames)]


def test_round_trip_identical_outputs(tmp_path, frames):
    model = random_model(7)
    path = str(tmp_path / "w.safetensors")
    export_weights(model, path, {"scenes": ["cornell"], "iterations": 10}, {"psnr": 30.5})
    loaded, meta = load_weights(path)
    assert meta["format"] == FORMAT and meta["version"] == "2"
    assert meta["config"] == model.cfg
    assert meta["provenance"] == {"scenes": ["cornell"], "iterations": 10}
    assert meta["metrics"] == {"psnr": 30.5}
    for k, v in model.state_dict().items():
        assert torch.equal(loaded.state_dict()[k], v), k
    for a, b in zip(_outputs(model, frames), _outputs(loaded, frames)):
        assert torch.equal(a, b)


def test_round_trip_non_default_config(tmp_path, frames):
    cfg = SSRConfig(tfa_hidden=4, k=4, enc=(8, 12, 16), feature_pool="avg")
    model = random_model(1, cfg)
    path = str(tmp_path / "w.safetensors")
    export_weights(model, path, RANDOM_PROVENANCE)
    loaded, meta = load_weights(path)
    assert meta["config"] == cfg
    assert loaded.state_dict()["unet.enc2.0.weight"].shape == (12, 11, 3, 3)
    for a, b in zip(_outputs(model, frames), _outputs(loaded, frames)):
        assert torch.equal(a, b)


def test_file_layout_and_metadata(tmp_path):
    path = str(tmp_path / "w.safetensors")
    model, _ = export_random(path, seed=0)
    with safe_open(path, framework="pt") as f:
        meta = f.metadata()
        assert meta["format"] == "subpixel-ssr"
        assert meta["version"] == "2"
        assert json.loads(meta["config"]) == SSRConfig().to_dict()
        assert json.loads(meta["provenance"]) == "random-init: for tests only, not a denoiser"
        assert json.loads(meta["metrics"]) == {}
        assert json.loads(meta["init"])["seed"] == 0
        assert sorted(f.keys()) == sorted(model.state_dict())
        w = f.get_tensor("tfa.ref.0.weight")
        assert w.shape == (8, 19, 3, 3) and w.dtype == torch.float32  # OIHW
        assert torch.equal(w, model.tfa.ref[0].weight)
        assert f.get_tensor("unet.dec1.2.bias").shape == (3,)


def test_writer_is_deterministic_and_readable():
    model = random_model(0)
    meta = {"b": "2", "a": "1", "format": FORMAT}
    a = safetensors_bytes(model.state_dict(), meta)
    b = safetensors_bytes(dict(reversed(list(model.state_dict().items()))), dict(reversed(list(meta.items()))))
    assert a == b
    n = int.from_bytes(a[:8], "little")
    assert n % 8 == 0
    from safetensors.torch import load

    back = load(a)
    for k, v in model.state_dict().items():
        assert torch.equal(back[k], v)


def _rewrite(src, dst, rename=None, reshape=None, drop=None, meta_patch=None, add=None):
    tensors = {}
    with safe_open(src, framework="pt") as f:
        meta = dict(f.metadata())
        for k in f.keys():
            tensors[k] = f.get_tensor(k)
    if rename:
        old, new = rename
        tensors[new] = tensors.pop(old)
    if reshape:
        name, shape = reshape
        tensors[name] = torch.zeros(shape)
    if drop:
        del tensors[drop]
    if add:
        tensors.update(add)
    if meta_patch:
        for k, v in meta_patch.items():
            if v is None:
                meta.pop(k, None)
            else:
                meta[k] = v
    with open(dst, "wb") as f:
        f.write(safetensors_bytes(tensors, meta))


@pytest.fixture
def good_file(tmp_path):
    path = str(tmp_path / "good.safetensors")
    export_random(path, seed=0)
    return path


def test_renamed_tensor_is_named(tmp_path, good_file):
    bad = str(tmp_path / "bad.safetensors")
    _rewrite(good_file, bad, rename=("unet.enc2.2.weight", "unet.enc2.3.weight"))
    with pytest.raises(WeightsError) as e:
        load_weights(bad)
    assert "missing tensor `unet.enc2.2.weight`" in str(e.value)
    assert "unexpected tensor `unet.enc2.3.weight`" in str(e.value)


def test_misshapen_tensor_is_named(tmp_path, good_file):
    bad = str(tmp_path / "bad.safetensors")
    _rewrite(good_file, bad, reshape=("tfa.emb.0.weight", (8, 14, 3, 3)))
    with pytest.raises(WeightsError, match=r"tensor `tfa\.emb\.0\.weight`: shape \[8, 14, 3, 3\], expected \[8, 15, 3, 3\]"):
        load_weights(bad)


def test_missing_and_extra_tensor_are_named(tmp_path, good_file):
    bad = str(tmp_path / "bad.safetensors")
    _rewrite(good_file, bad, drop="unet.dec1.0.bias")
    with pytest.raises(WeightsError, match=r"missing tensor `unet\.dec1\.0\.bias`"):
        load_weights(bad)
    _rewrite(good_file, bad, add={"unet.extra.weight": torch.zeros(2)})
    with pytest.raises(WeightsError, match=r"unexpected tensor `unet\.extra\.weight`"):
        load_weights(bad)


def test_config_mismatch_names_tensors(tmp_path, good_file):
    bad = str(tmp_path / "bad.safetensors")
    cfg = SSRConfig(enc=(16, 32, 48)).to_json()
    _rewrite(good_file, bad, meta_patch={"config": cfg})
    with pytest.raises(WeightsError, match=r"tensor `unet\.enc3\.0\.weight`: shape \[28, 35, 3, 3\], expected \[48, 35, 3, 3\]"):
        load_weights(bad)


@pytest.mark.parametrize(
    "patch, message",
    [
        ({"format": "pytorch"}, "`format` is 'pytorch'"),
        ({"format": None}, "`format` is None"),
        ({"version": "3"}, "`version` is '3', this code reads versions ['1', '2']"),
        ({"version": "1"}, "`version` is '1' but its config is version 2"),
        ({"config": None}, "no `config`"),
        ({"config": "{not json"}, "`config`: config: not valid JSON"),
        ({"config": '{"k": 8}'}, "missing key"),
        ({"provenance": None}, "no `provenance`"),
        ({"metrics": "{"}, "`metrics` is not valid JSON"),
    ],
)
def test_bad_metadata(tmp_path, good_file, patch, message):
    bad = str(tmp_path / "bad.safetensors")
    _rewrite(good_file, bad, meta_patch=patch)
    with pytest.raises(WeightsError) as e:
        load_weights(bad)
    assert message in str(e.value)


def test_no_metadata_and_garbage(tmp_path):
    p = str(tmp_path / "plain.safetensors")
    with open(p, "wb") as f:
        f.write(safetensors_bytes({"x": torch.zeros(1)}, {}))
    with pytest.raises(WeightsError, match="no __metadata__"):
        load_weights(p)
    g = str(tmp_path / "garbage.safetensors")
    with open(g, "wb") as f:
        f.write(b"\x10\x00\x00\x00\x00\x00\x00\x00not json at all!")
    with pytest.raises(WeightsError, match="not a readable safetensors file"):
        load_weights(g)


def test_cli_random(tmp_path):
    out = tmp_path / "r.safetensors"
    subprocess.run(
        [sys.executable, "-m", "ssr.export", "--random", "--seed", "0", "--out", str(out)],
        cwd=TRAINING,
        check=True,
        capture_output=True,
    )
    model, meta = load_weights(str(out))
    assert meta["provenance"] == RANDOM_PROVENANCE
    ref = random_model(0)
    for k, v in ref.state_dict().items():
        assert torch.equal(model.state_dict()[k], v), k
    other = tmp_path / "same.safetensors"
    export_random(str(other), seed=0)
    assert out.read_bytes() == other.read_bytes()


def test_version_1_files_load_with_the_v1_pipeline(tmp_path, frames):
    """Weights trained before exposure normalisation keep their meaning (model.LEGACY_OPTIONS)."""
    from ssr.model import LEGACY_OPTIONS

    legacy = SSRConfig(version=1, **LEGACY_OPTIONS)
    model = random_model(3, legacy)
    path = str(tmp_path / "v1.safetensors")
    export_weights(model, path, RANDOM_PROVENANCE)
    with safe_open(path, framework="pt") as f:
        assert f.metadata()["version"] == "1"
        assert "exposure" not in json.loads(f.metadata()["config"])
    loaded, meta = load_weights(path)
    assert meta["version"] == "1" and meta["config"] == legacy
    assert (loaded.cfg.exposure, loaded.cfg.remodulation, loaded.cfg.history) == ("none", "accumulated", "screen")
    for a, b in zip(_outputs(model, frames), _outputs(loaded, frames)):
        assert torch.equal(a, b)
    # a version-1 config naming a version-2 option is an error naming it
    bad = str(tmp_path / "bad.safetensors")
    cfg = dict(legacy.to_dict(), exposure="channel")
    _rewrite(path, bad, meta_patch={"config": json.dumps(cfg)})
    with pytest.raises(WeightsError, match=r"version 1 has no option\(s\) \['exposure'\]"):
        load_weights(bad)


def test_shipped_weights_load():
    """The weights in weights/ (version 1 until retrained) keep loading, with their own pipeline."""
    import glob

    shipped = sorted(glob.glob(os.path.join(os.path.dirname(TRAINING), "weights", "ssr*.safetensors")))
    assert shipped
    for path in shipped:
        model, meta = load_weights(path)
        assert meta["version"] in ("1", "2"), path
        assert model.cfg.version == int(meta["version"]), path


def test_set_options_rewrites_config_and_keeps_tensors(tmp_path):
    """`python -m ssr.export --from F --option ceiling=max`: same tensors, new config, the change
    in the provenance, old metrics dropped; bad options are named."""
    from ssr.export import set_options

    cfg = SSRConfig(ceiling="none")
    model = random_model(3, cfg)
    src = str(tmp_path / "old.safetensors")
    export_weights(model, src, {"iterations": 5}, {"psnr": 20.0})
    out = str(tmp_path / "new.safetensors")
    assert set_options(src, ["ceiling=max"], out) == {}
    new, meta = load_weights(out)
    assert meta["config"].ceiling == "max" and meta["config"].enc == cfg.enc
    assert meta["metrics"] == {}
    assert meta["provenance"]["iterations"] == 5
    (change,) = meta["provenance"]["options_set"]
    assert (change["option"], change["from"], change["to"]) == ("ceiling", "none", "max")
    for k, v in model.state_dict().items():
        assert torch.equal(new.state_dict()[k], v), k
    with pytest.raises(WeightsError, match="KEY=VALUE"):
        set_options(src, ["widths=3"], out)
    with pytest.raises(WeightsError, match="ceiling"):
        set_options(out, ["exposure=none"], str(tmp_path / "bad.safetensors"))  # the ceiling needs the exposure

    # An option of the engine's output pass changes the metrics too (validation scores the
    # engine's output, the output pass included): dropped as well.
    kept = str(tmp_path / "kept.safetensors")
    assert set_options(src, ["mean_correction=tiles"], kept) == {}
    _, meta = load_weights(kept)
    assert meta["config"].mean_correction == "tiles" and meta["metrics"] == {}
    assert meta["config"].to_dict()["mean_correction"] == "tiles"
