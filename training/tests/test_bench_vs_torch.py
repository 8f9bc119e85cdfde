"""Tests for bench_vs_torch.py: the ratio it prints comes from the two benchmarks' own
medians (stand-in engine binary and PyTorch results with known times), and a missing binary
is an error naming it."""

import json
import os
import stat

import pytest

import bench_vs_torch as bvt


def _fake_engine(tmp_path, times, output_ms):
    """A stand-in `subpixel` that prints `bench denoise --json` output, one frame time per
    call, of which `output_ms` in the output stage."""
    counter = tmp_path / "calls"
    counter.write_text("0")
    script = tmp_path / "subpixel"
    script.write_text(
        "#!/usr/bin/env python3\n"
        "import json, pathlib\n"
        f"c = pathlib.Path({str(counter)!r}); n = int(c.read_text()); c.write_text(str(n + 1))\n"
        f"times = {times!r}\n"
        f"stages = [{{'stage': 'unet', 'stats': {{'median_ms': times[n] - {output_ms!r}}}}}, "
        f"{{'stage': 'output', 'stats': {{'median_ms': {output_ms!r}}}}}]\n"
        "print(json.dumps({'total_ms': times[n], 'stages': stages, 'adapter': 'stand-in adapter'}))\n"
    )
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    return script


def test_ratio_is_median_engine_over_median_torch(tmp_path, monkeypatch, capsys):
    """Both ratios, the network's (the engine without its output stage against PyTorch's
    tfa + unet) and the frame's, from each side's medians over the rounds."""
    engine = _fake_engine(tmp_path, [30.0, 10.0, 20.0], 4.0)
    torch_times = iter([(4.0, 2.0), (6.0, 8.0), (5.0, 3.2)])

    def fake_torch(python, weights, w, h, frames, device):
        total, network = next(torch_times)
        return {"results": [{"stages": {"total": {"median_ms": total}, "network": {"median_ms": network}}}],
                "device_name": "stand-in CPU", "torch": "0"}

    monkeypatch.setattr(bvt, "run_torch", fake_torch)
    weights = tmp_path / "w.safetensors"
    weights.write_bytes(b"x")
    out_json = tmp_path / "r.json"
    assert bvt.main(["--bin", str(engine), "--weights", str(weights), "--rounds", "3", "--json", str(out_json)]) == 0
    out = capsys.readouterr().out
    # Frame medians: engine 20, PyTorch 5 -> 4.00; network: engine 16 (20 - 4), PyTorch 3.2 -> 5.00.
    assert "frame (with the output pass): engine 20.00 ms, PyTorch 5.00 ms, engine / PyTorch = 4.00" in out
    assert "network: engine 16.00 ms, PyTorch 3.20 ms, engine / PyTorch = 5.00" in out
    res = json.loads(out_json.read_text())
    assert res["ratio"] == pytest.approx(4.0)
    assert res["network_ratio"] == pytest.approx(5.0)


def test_a_cpu_adapter_is_timed_by_its_wall_time():
    """On a CPU driver the engine's frame is its CPU wall time, the network its share by the
    stages' timestamps; elsewhere the timestamps' sum."""
    stages = [{"stage": "unet", "stats": {"median_ms": 6.0}}, {"stage": "output", "stats": {"median_ms": 2.0}}]
    eng = {"total_ms": 8.0, "wall_ms": 12.0, "cpu_adapter": True, "stages": stages}
    assert bvt.engine_frame_ms(eng) == pytest.approx(12.0)
    assert bvt.engine_network_ms(eng) == pytest.approx(9.0)
    gpu = dict(eng, cpu_adapter=False)
    assert bvt.engine_frame_ms(gpu) == pytest.approx(8.0)
    assert bvt.engine_network_ms(gpu) == pytest.approx(6.0)


def test_missing_binary_is_named(tmp_path, capsys):
    missing = tmp_path / "no-such-subpixel"
    with pytest.raises(SystemExit):
        bvt.main(["--bin", str(missing)])
    assert str(missing) in capsys.readouterr().err


def test_relative_paths_reach_both_sides_absolute(tmp_path, monkeypatch, capsys):
    """PyTorch's side runs in training/: weights given relative to the caller's folder (the
    README's `--weights weights/ssr.safetensors` from the repository root) reach it as the
    same file, absolute."""
    engine = _fake_engine(tmp_path, [10.0], 1.0)
    (tmp_path / "weights").mkdir()
    (tmp_path / "weights" / "w.safetensors").write_bytes(b"x")
    seen = []

    def fake_torch(python, weights, w, h, frames, device):
        seen.append(weights)
        return {"results": [{"stages": {"total": {"median_ms": 5.0}, "network": {"median_ms": 4.0}}}],
                "device_name": "stand-in CPU", "torch": "0"}

    monkeypatch.setattr(bvt, "run_torch", fake_torch)
    monkeypatch.chdir(tmp_path)
    assert bvt.main(["--bin", "subpixel", "--weights", "weights/w.safetensors", "--rounds", "1"]) == 0
    assert seen == [str(tmp_path / "weights" / "w.safetensors")]
