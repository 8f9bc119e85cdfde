import json
import os
import re
import shutil

import numpy as np
import pytest
import torch

from ssr.data import (
    EXR_CHANNELS,
    THIN_KEEP_MIN,
    DatasetError,
    SequenceDataset,
    WindowKey,
    WindowSampler,
    check_dataset,
    collate,
    effective_crop,
    flip_frame,
    pad_frame,
    read_exr,
    thin_frame,
    to_frame,
    write_exr,
)
from ssr.model import FRAME_CHANNELS, warp
from ssr.synth import make_sequence, write_sequence

from conftest import DATASET_FRAMES, DATASET_SIZE


def source(ds, key_seq, t):
    """The synthetic frame as written (dict of CHW arrays), regenerated from its seed."""
    s = ds.sequences[key_seq]
    return make_sequence(s.width, s.height, s.frames, s.meta["seed"], scene_seed=0)[t]


def test_exr_roundtrip(tmp_path):
    rng = np.random.default_rng(0)
    bufs = {"color": rng.normal(size=(3, 5, 7)).astype(np.float32), "mask": rng.random((1, 5, 7)).astype(np.float32)}
    p = str(tmp_path / "a.exr")
    write_exr(p, bufs)
    arr = read_exr(p, ["color.R", "color.G", "color.B", "mask.Y"])
    assert arr.shape == (5, 7, 4) and arr.dtype == np.float32
    np.testing.assert_array_equal(arr[..., :3].transpose(2, 0, 1), bufs["color"])
    np.testing.assert_array_equal(arr[..., 3], bufs["mask"][0])
    assert len(EXR_CHANNELS) == 24 and EXR_CHANNELS[0] == "color.R" and EXR_CHANNELS[-1] == "reference.B"


def test_windows_and_items(dataset):
    ds = SequenceDataset(dataset, "train", crop=None, flips=False)
    assert len(ds.sequences) == 2
    assert len(ds) == 2 * (DATASET_FRAMES - 5 + 1)
    item = ds[1]  # sequence 0, window starting at frame 1, whole frame
    assert len(item) == 5
    for t, f in enumerate(item):
        assert set(f) == set(FRAME_CHANNELS) | {"reference"}
        for k, c in FRAME_CHANNELS.items():
            assert f[k].shape == (c, DATASET_SIZE, DATASET_SIZE) and f[k].dtype == torch.float32
        src = source(ds, 0, t + 1)
        for k in f:
            np.testing.assert_array_equal(f[k].numpy(), src[k], err_msg=k)


def test_crop_and_flips_match_source(dataset):
    ds = SequenceDataset(dataset, "train", crop=16)
    assert ds.crop_hw == (16, 16)
    src = source(ds, 1, 1)
    for hf in (False, True):
        for vf in (False, True):
            f = ds[WindowKey(1, 1, 4, 10, hf, vf)][0]
            for k, v in f.items():
                want = src[k][:, 4:20, 10:26]
                if hf:
                    want = want[:, :, ::-1]
                if vf:
                    want = want[:, ::-1, :]
                if k == "motion":
                    want = want * np.array([-1.0 if hf else 1.0, -1.0 if vf else 1.0], np.float32)[:, None, None]
                np.testing.assert_array_equal(v.numpy(), want, err_msg=f"{k} h={hf} v={vf}")


def test_flip_motion_sign_commutes_with_warp():
    # warp(flip(src), flip(motion)) == flip(warp(src, motion)): the sign convention is right.
    g = torch.Generator().manual_seed(0)
    src = torch.rand(1, 3, 16, 20, generator=g)
    motion = (torch.rand(1, 2, 16, 20, generator=g) - 0.5) * 3.0
    ref, ref_valid = warp(src, motion)
    for hf, vf in ((True, False), (False, True), (True, True)):
        fl = flip_frame({"s": src, "motion": motion}, hf, vf)
        out, valid = warp(fl["s"], fl["motion"])
        back = flip_frame({"s": out, "v": valid}, hf, vf)
        both = (back["v"] > 0) & (ref_valid > 0)
        assert both.float().mean() > 0.6
        torch.testing.assert_close(back["s"] * both, ref * both, atol=1e-5, rtol=0)
    # a wrong sign does not commute
    bad = flip_frame({"s": src}, True, False)
    out, valid = warp(bad["s"], motion)
    back = flip_frame({"s": out}, True, False)["s"]
    assert (back - ref).abs().max() > 0.1


def test_sampler_keys(dataset):
    ds = SequenceDataset(dataset, "train", crop=16)
    s0 = WindowSampler(ds, 4, 0, 3, seed=7, rank=0)
    batches = list(s0)
    assert len(batches) == 3 and all(len(b) == 4 for b in batches)
    # a resumed sampler gives the same keys for the same iterations; another rank others
    assert list(WindowSampler(ds, 4, 1, 3, seed=7, rank=0)) == batches[1:]
    assert WindowSampler(ds, 4, 0, 1, seed=7, rank=1).keys(0) != batches[0]
    keys = [k for b in WindowSampler(ds, 8, 0, 20, seed=1) for k in b]
    assert {k.hflip for k in keys} == {False, True} and {k.vflip for k in keys} == {False, True}
    assert {k.seq for k in keys} == {0, 1}
    for k in keys:
        assert k.x0 % 2 == 0 and k.y0 % 2 == 0
        assert 0 <= k.x0 <= DATASET_SIZE - 16 and 0 <= k.y0 <= DATASET_SIZE - 16
        assert 0 <= k.start <= DATASET_FRAMES - 5
    noflip = SequenceDataset(dataset, "train", crop=16, flips=False)
    assert not any(k.hflip or k.vflip for b in WindowSampler(noflip, 8, 0, 5) for k in b)


def test_dataloader_collate_and_caches(dataset, tmp_path):
    ds = SequenceDataset(dataset, "train", crop=16)
    loader = torch.utils.data.DataLoader(ds, batch_sampler=WindowSampler(ds, 3, 0, 2, seed=2), collate_fn=collate)
    batches = list(loader)
    assert len(batches) == 2
    b = batches[0]
    assert len(b) == 5 and b[0]["color"].shape == (3, 3, 16, 16) and b[4]["motion"].shape == (3, 2, 16, 16)
    keys = WindowSampler(ds, 3, 0, 1, seed=2).keys(0)
    for cache in ("memory", "disk"):
        dc = SequenceDataset(dataset, "train", crop=16, cache=cache, cache_dir=str(tmp_path / "cache"))
        for _ in range(2):  # second pass: from the cache
            got = collate([dc[k] for k in keys])
            for t in range(5):
                for k in got[t]:
                    torch.testing.assert_close(got[t][k], b[t][k], rtol=0, atol=0)
    assert any(f.endswith(".npy") for _, _, fs in os.walk(tmp_path / "cache") for f in fs)


def test_small_frames_use_the_whole_frame_cut_to_multiple_of_4(tmp_path):
    root = str(tmp_path / "ds")
    write_sequence(os.path.join(root, "train", "a"), "train", 0, 5, width=30, height=22, seed=1)
    ds = SequenceDataset(root, "train", crop=256)
    assert ds.crop_hw == (20, 28)
    item = ds[WindowSampler(ds, 1, 0, 1).keys(0)[0]]
    assert item[0]["color"].shape == (3, 20, 28)
    with pytest.raises(ValueError, match="multiple of 4"):
        effective_crop(ds.sequences, 30)


def test_pad_frame_replicates_edges():
    f = {"x": torch.arange(6.0).view(1, 1, 2, 3)}
    p, (h, w) = pad_frame(f)
    assert (h, w) == (2, 3) and p["x"].shape == (1, 1, 4, 4)
    assert p["x"][0, 0, 3, 3] == 5.0 and p["x"][0, 0, 0, 3] == 2.0


# ----------------------------------------------------------------------------- errors


def make_seq(tmp_path, frames=5, size=8):
    root = str(tmp_path / "ds")
    folder = write_sequence(os.path.join(root, "train", "s0"), "train", 0, frames, size, size, seed=2)
    return root, folder


def test_missing_frame_is_named(tmp_path):
    root, folder = make_seq(tmp_path)
    os.remove(os.path.join(folder, "frame_0003.exr"))
    with pytest.raises(DatasetError, match=r"frame_0003\.exr: missing frame"):
        SequenceDataset(root, "train", crop=8)
    assert any("frame_0003.exr" in p for p in check_dataset(root))


def _without_depth():
    fr = make_sequence(8, 8, 5, 2)[2]
    del fr["depth"]
    return fr


@pytest.mark.parametrize(
    "index, make_frame, message",
    [
        (2, _without_depth, r"frame_0002\.exr: missing channel\(s\) \['depth\.Y'\]"),
        (1, lambda: make_sequence(12, 8, 2, 2)[1], r"frame_0001\.exr: frame is 12x8 but .*sequence\.json says 8x8"),
    ],
    ids=["missing-channel", "mismatched-size"],
)
def test_bad_frame_is_named(tmp_path, index, make_frame, message):
    root, folder = make_seq(tmp_path)
    write_exr(os.path.join(folder, f"frame_{index:04d}.exr"), make_frame())
    ds = SequenceDataset(root, "train", crop=8)
    with pytest.raises(DatasetError, match=message):
        ds[0]
    assert any(re.search(message, p) for p in check_dataset(root))


def test_bad_sequence_json(tmp_path):
    root, folder = make_seq(tmp_path)
    jp = os.path.join(folder, "sequence.json")
    meta = json.load(open(jp))
    del meta["width"]
    json.dump(meta, open(jp, "w"))
    with pytest.raises(DatasetError, match=r"sequence\.json: missing key\(s\) \['width'\]"):
        SequenceDataset(root, "train")
    meta["width"] = 8
    meta["split"] = "test"
    json.dump(meta, open(jp, "w"))
    with pytest.raises(DatasetError, match="split"):
        SequenceDataset(root, "train")
    os.remove(jp)
    with pytest.raises(DatasetError, match="missing sequence.json"):
        SequenceDataset(root, "train")
    with pytest.raises(DatasetError, match="no such split"):
        SequenceDataset(root, "val")


def test_short_sequence_and_unknown_scene(tmp_path):
    root, _ = make_seq(tmp_path, frames=3)
    with pytest.raises(DatasetError, match="fewer than the window of 5"):
        SequenceDataset(root, "train")
    with pytest.raises(DatasetError, match=r"scene\(s\) \['nope'\]"):
        SequenceDataset(root, "train", window=3, scenes=["nope"])


def test_non_finite_values_are_sanitised_except_motion(tmp_path):
    root, folder = make_seq(tmp_path)
    fr = make_sequence(8, 8, 5, 2)[0]
    fr["color"][0, 0, 0] = np.nan
    fr["reference"][1, 1, 1] = np.inf
    fr["motion"][0, 2, 2] = np.nan
    write_exr(os.path.join(folder, "frame_0000.exr"), fr)
    f = SequenceDataset(root, "train", crop=8, flips=False)[0][0]
    assert f["color"][0, 0, 0] == 0 and f["reference"][1, 1, 1] == 0
    assert torch.isnan(f["motion"][0, 2, 2])
    assert torch.isfinite(to_frame(np.zeros((2, 2, 24), np.float32))["color"]).all()


def test_split_mixing_spp_or_sizes_is_named(tmp_path):
    root, folder = make_seq(tmp_path)
    other = write_sequence(os.path.join(root, "train", "s1"), "train", 1, 5, 12, 12, seed=3)
    # different sizes: fine for crops (the crop fits both), an error for whole frames
    assert len(SequenceDataset(root, "train", crop=8).sequences) == 2
    with pytest.raises(DatasetError, match=r"s1/sequence\.json: 12x12 frames, but .*s0/sequence\.json has 8x8"):
        SequenceDataset(root, "train", crop=None)
    # different reference sample counts: always an error naming both files
    jp = os.path.join(other, "sequence.json")
    meta = json.load(open(jp))
    meta["spp"] = meta["spp"] * 2
    json.dump(meta, open(jp, "w"))
    with pytest.raises(DatasetError, match=r"s1/sequence\.json: spp \d+, but .*s0/sequence\.json has spp \d+"):
        SequenceDataset(root, "train", crop=8)


def test_thinning_keeps_every_pixels_expectation():
    # Russian roulette on the samples: over many thinned copies the mean of each traced
    # pixel's color is the original (independent check: the per-pixel mean of 4,000 draws
    # against the source, within 5 standard errors), untraced pixels and the other buffers
    # are untouched, and about `keep` of the traced samples survive.
    g = torch.Generator().manual_seed(3)
    h, w = 8, 8
    mask = torch.zeros(1, h, w)
    mask[:, ::2, ::2] = 1.0
    color = torch.rand(3, h, w, generator=g) * mask
    frame = {"color": color, "mask": mask, "shadow": torch.rand(3, h, w, generator=g), "albedo": torch.rand(3, h, w, generator=g)}
    keep, n = 0.25, 4000
    acc = torch.zeros_like(color)
    acc2 = torch.zeros_like(color)
    survived = 0.0
    for i in range(n):
        out = thin_frame(frame, keep, torch.Generator().manual_seed(i))
        acc += out["color"]
        acc2 += out["color"] ** 2
        survived += float(((out["color"].amax(0, keepdim=True) > 0) & (mask > 0)).sum()) / float(mask.sum())
        assert torch.equal(out["albedo"], frame["albedo"]) and torch.equal(out["mask"], mask)
        assert torch.equal(out["color"] * (1 - mask), color * (1 - mask))
        dropped = (mask > 0) & (out["color"].amax(0, keepdim=True) == 0)
        assert torch.all(out["shadow"][dropped.expand(3, h, w)] == 0)
    mean = acc / n
    se = ((acc2 / n - mean**2).clamp(min=0) / n).sqrt()
    traced = mask.expand(3, h, w) > 0
    assert torch.all((mean - color).abs()[traced] <= 5 * se[traced] + 1e-6)
    assert abs(survived / n - keep) < 0.02


def test_thinning_is_deterministic_and_off_by_default(dataset):
    plain = SequenceDataset(dataset, "train", crop=16)
    g1, g2 = torch.Generator().manual_seed(5), torch.Generator().manual_seed(5)
    k_plain = [plain.random_key(g1) for _ in range(20)]
    k_again = [SequenceDataset(dataset, "train", crop=16).random_key(g2) for _ in range(20)]
    assert k_plain == k_again and all(k.keep == 1.0 for k in k_plain)
    thin = SequenceDataset(dataset, "train", crop=16, thin=1.0)
    g = torch.Generator().manual_seed(5)
    keys = [thin.random_key(g) for _ in range(20)]
    assert all(THIN_KEEP_MIN <= k.keep < 1.0 for k in keys)
    # a lower floor reaches below the default's (keep log-uniform in [0.01, 1])
    low = SequenceDataset(dataset, "train", crop=16, thin=1.0, thin_keep_min=0.01)
    gl = torch.Generator().manual_seed(5)
    lows = [low.random_key(gl).keep for _ in range(200)]
    assert all(0.01 <= k < 1.0 for k in lows) and min(lows) < THIN_KEEP_MIN
    with pytest.raises(ValueError, match="thin_keep_min"):
        SequenceDataset(dataset, "train", crop=16, thin=1.0, thin_keep_min=0.0)
    # the choices before thinning are those of the plain dataset
    assert [k[:6] for k in keys[:1]] == [k[:6] for k in k_plain[:1]]
    a, b = thin[keys[0]], thin[keys[0]]
    for fa, fb in zip(a, b):
        for k in fa:
            assert torch.equal(fa[k], fb[k])
    with pytest.raises(ValueError, match="thin"):
        SequenceDataset(dataset, "train", crop=16, thin=1.5)



def test_extra_buffers_load_beside_the_frame(tmp_path):
    """`extra=("full",)` adds the 1-spp frame, cropped and flipped with the rest, through
    every cache; a dataset without it is an error naming the frame and the channels."""
    from ssr.data import frame_name, layout, read_exr
    from ssr.synth import write_dataset

    root = write_dataset(str(tmp_path / "d"), {"train": 1}, 5, 16, 16, seed=4, full=True)
    seq = os.path.join(root, "train", "synthetic_000")
    full0 = read_exr(os.path.join(seq, frame_name(0)), ["full.R", "full.G", "full.B"])
    channels, offsets = layout(("full",))
    assert channels[-3:] == ("full.R", "full.G", "full.B") and offsets["full"] == (24, 27)
    plain = SequenceDataset(root, "train", crop=8, flips=True)
    key = WindowSampler(plain, 1, 0, 1, seed=5).keys(0)[0]._replace(hflip=True, vflip=False)
    for cache in ("none", "memory", "disk"):
        ds = SequenceDataset(root, "train", crop=8, flips=True, extra=("full",), cache=cache, cache_dir=str(tmp_path / "c"))
        whole = ds.full_frame(0, 0)
        torch.testing.assert_close(whole["full"], torch.from_numpy(full0.transpose(2, 0, 1).copy()), rtol=0, atol=0)
        for _ in range(2):
            got, ref = ds[key], plain[key]
            for t in range(5):
                for k in ref[t]:  # the usual buffers are untouched
                    torch.testing.assert_close(got[t][k], ref[t][k], rtol=0, atol=0)
            f = read_exr(os.path.join(seq, frame_name(key.start)), ["full.R", "full.G", "full.B"]).transpose(2, 0, 1)
            crop = f[:, key.y0 : key.y0 + 8, key.x0 : key.x0 + 8][:, :, ::-1]  # hflip
            torch.testing.assert_close(got[0]["full"], torch.from_numpy(crop.copy()), rtol=0, atol=0)
    with pytest.raises(ValueError, match="extra buffers must be among"):
        SequenceDataset(root, "train", crop=8, extra=("nope",))
    bare = write_dataset(str(tmp_path / "b"), {"train": 1}, 5, 16, 16, seed=4)
    with pytest.raises(DatasetError, match=r"frame_0000\.exr: missing channel\(s\) \['full\.R'"):
        SequenceDataset(bare, "train", crop=8, extra=("full",)).full_frame(0, 0)


def test_noisy_reference_sequences_are_left_out_on_request(tmp_path):
    """`min_reference_psnr` drops the training sequences whose sequence.json records a mean
    PSNR between reference halves below it, keeps the rest, and without it keeps all; a
    sequence without the record, or a threshold that leaves nothing, is an error naming the
    file or the folder."""
    from ssr.synth import write_dataset

    root = write_dataset(str(tmp_path / "ds"), {"train": 3}, 5, 16, 16, seed=4)
    names = sorted(os.listdir(os.path.join(root, "train")))
    noise = dict(zip(names, [15.0, 31.5, 24.0]))

    def record(name, value):
        path = os.path.join(root, "train", name, "sequence.json")
        with open(path) as f:
            meta = json.load(f)
        if value is None:
            meta.pop("reference_noise", None)
        else:
            meta["reference_noise"] = {"frames": 5, "mean_psnr_db": value, "min_psnr_db": value - 1}
        with open(path, "w") as f:
            json.dump(meta, f)
        return path

    for name, value in noise.items():
        record(name, value)
    everything = SequenceDataset(root, "train", window=3, crop=16)
    assert sorted(s.name for s in everything.sequences) == names and everything.noisy == []
    ds = SequenceDataset(root, "train", window=3, crop=16, min_reference_psnr=24.0)
    assert sorted(s.name for s in ds.sequences) == sorted(n for n, v in noise.items() if v >= 24.0)
    assert [s.name for s in ds.noisy] == [n for n, v in noise.items() if v < 24.0]
    # Windows come only from the kept sequences.
    assert {ds.sequences[si].name for si, _ in ds.windows} == {s.name for s in ds.sequences}
    with pytest.raises(DatasetError, match="every sequence's reference noise is below 40"):
        SequenceDataset(root, "train", window=3, crop=16, min_reference_psnr=40.0)
    missing = record(names[1], None)
    with pytest.raises(DatasetError, match=re.escape(missing) + ".*reference_noise"):
        SequenceDataset(root, "train", window=3, crop=16, min_reference_psnr=20.0)
    # Without the threshold the record is not needed.
    assert len(SequenceDataset(root, "train", window=3, crop=16).sequences) == 3


def test_colour_permutation_permutes_every_rgb_buffer_alike(dataset):
    from ssr.data import RGB_BUFFERS, RGB_PERMUTATIONS, permute_colors

    ds = SequenceDataset(dataset, "train", crop=16)
    plain = ds[WindowKey(1, 1, 4, 10, True, False)]
    assert {"color", "albedo", "shadow", "transparent", "reference"} <= set(RGB_BUFFERS)
    # the extra buffers the background loss and the emission and footprint models read
    assert {"background", "emission", "emission_footprint", "albedo_footprint", "full", "reference_half"} <= set(RGB_BUFFERS)
    assert not {"normal", "motion", "mask", "depth", "metallic", "roughness", "coverage"} & set(RGB_BUFFERS)
    assert sorted(RGB_PERMUTATIONS) == sorted(
        (a, b, c) for a in range(3) for b in range(3) for c in range(3) if len({a, b, c}) == 3
    )
    for perm, order in enumerate(RGB_PERMUTATIONS):
        got = ds[WindowKey(1, 1, 4, 10, True, False, 1.0, 0, perm)]
        for f, p in zip(got, plain):
            for k, v in f.items():
                want = p[k][list(order)] if k in RGB_BUFFERS else p[k]
                assert torch.equal(v, want), f"{k} perm {perm}"
        # the same on a batch (NCHW), and 0 is the identity
        batch = collate([plain])[0]
        permuted = permute_colors(batch, perm)
        for k in batch:
            want = batch[k][:, list(order)] if k in RGB_BUFFERS else batch[k]
            assert torch.equal(permuted[k], want), k
    assert permute_colors(plain[0], 0) is plain[0]


def test_colour_permutation_is_drawn_last_and_off_by_default(dataset):
    plain = SequenceDataset(dataset, "train", crop=16)
    perm = SequenceDataset(dataset, "train", crop=16, color_permute=True)
    g1, g2 = torch.Generator().manual_seed(9), torch.Generator().manual_seed(9)
    k_plain = [plain.random_key(g1) for _ in range(60)]
    k_perm = [perm.random_key(g2) for _ in range(60)]
    assert all(k.perm == 0 for k in k_plain)
    assert {k.perm for k in k_perm} == set(range(6))
    # the choices before the permutation are those of the plain dataset
    assert k_perm[0][:8] == k_plain[0][:8]
    # resumable: the keys of an iteration follow from (seed, rank, iteration) alone
    assert WindowSampler(perm, 4, 3, 4, seed=2).keys(3) == list(WindowSampler(perm, 4, 0, 5, seed=2))[3]
