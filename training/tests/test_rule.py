import json

import pytest

from ssr import rule


def cell(psnr, ssim):
    return {"psnr": psnr, "ssim": ssim, "temporal": 0.02, "brightness": 0.05, "sequences": 1, "of": 1}


def table(**methods):
    return [{"method": m, "scenes": {c: cell(*v) for c, v in cols.items()}} for m, cols in methods.items()]


T = table(
    inc={"a": (30.0, 0.80), "b": (20.0, 0.60)},  # mean 25.00 / 0.70
    up={"a": (29.98, 0.81), "b": (19.96, 0.60)},  # 24.97 / 0.705: SSIM up, PSNR within 0.05
    costly={"a": (29.8, 0.82), "b": (20.0, 0.60)},  # 24.90 / 0.71: SSIM up, PSNR 0.10 down
    flat={"a": (31.0, 0.80), "b": (21.0, 0.60)},  # 26.00 / 0.70: PSNR up, SSIM equal
)


def test_means_are_the_tables_mean_column():
    assert rule.column_means(T, "inc") == pytest.approx((25.0, 0.70))
    assert rule.column_means(T, "costly", ["b"]) == pytest.approx((20.0, 0.60))


@pytest.mark.parametrize(
    "challenger,cols,picked",
    [
        ("up", None, True),  # higher SSIM, PSNR 0.03 lower: within the margin
        ("costly", None, False),  # higher SSIM but 0.10 dB lower
        ("flat", None, False),  # SSIM not higher: PSNR alone never wins
        ("costly", ["a"], False),  # column a alone: SSIM 0.82 > 0.80, but 29.8 < 30.0 - 0.05
        ("up", ["a"], True),  # column a alone: 0.81 > 0.80, 29.98 >= 29.95
    ],
)
def test_standing_rule(challenger, cols, picked):
    inc = rule.column_means(T, "inc", cols)
    got, reason = rule.decide(inc, rule.column_means(T, challenger, cols))
    assert got is picked, reason


def test_margin_is_inclusive():
    assert rule.decide((25.0, 0.70), (24.95, 0.7001))[0]
    assert not rule.decide((25.0, 0.70), (24.9499, 0.7001))[0]


def test_cli_prints_the_winner_and_names_bad_input(tmp_path, capsys):
    path = tmp_path / "val.json"
    path.write_text(json.dumps(T))
    assert rule.main([str(path), "--incumbent", "inc", "--challenger", "up", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["winner"] == "up" and out["up"]["psnr"] == pytest.approx(24.97)
    assert rule.main([str(path), "--incumbent", "inc", "--challenger", "costly"]) == 0
    assert "winner: inc" in capsys.readouterr().out
    assert rule.main([str(path), "--incumbent", "inc", "--challenger", "nope"]) == 2
    assert "method 'nope' is not in the table" in capsys.readouterr().err
    assert rule.main([str(path), "--incumbent", "inc", "--challenger", "up", "--columns", "c"]) == 2
    assert "no score in column(s) c" in capsys.readouterr().err
    (tmp_path / "bad.json").write_text("{}")
    assert rule.main([str(tmp_path / "bad.json"), "--incumbent", "inc", "--challenger", "up"]) == 2
    assert "expected the JSON list" in capsys.readouterr().err


def test_guard_columns_limit_the_drop(tmp_path, capsys):
    t = table(
        inc={"p": (25.0, 0.70), "f1": (30.0, 0.9), "f2": (28.0, 0.8)},
        ok={"p": (25.2, 0.72), "f1": (29.8, 0.9), "f2": (27.8, 0.8)},  # fixed mean -0.20 dB
        bad={"p": (25.2, 0.72), "f1": (29.5, 0.9), "f2": (27.8, 0.8)},  # fixed mean -0.35 dB
    )
    path = tmp_path / "val.json"
    path.write_text(json.dumps(t))
    args = ["--incumbent", "inc", "--columns", "p", "--guard-columns", "f1,f2", "--guard-db", "0.3", "--json"]
    assert rule.main([str(path), "--challenger", "ok", *args]) == 0
    assert json.loads(capsys.readouterr().out)["winner"] == "ok"
    assert rule.main([str(path), "--challenger", "bad", *args]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["winner"] == "inc" and "more than 0.3 dB below" in out["reason"]
    assert rule.guard(28.0, 27.7, 0.3)[0] and not rule.guard(28.0, 27.69, 0.3)[0]
