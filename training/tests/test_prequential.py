"""F12's prequential ledger (weights/README, forty-second session): each block's entry is
the standing rule between the shipped model and F12 before it saw the block, and F12 ships
only after two consecutive blocks go to it."""

import json

import pytest

from ssr.prequential import entry, load, main, record, ships
from ssr.registered import GUARD_COLUMNS
from ssr.rule import RuleError


def table(shipped, f12):
    """Rows as `subpixel eval --table --json` prints them: (procedural PSNR, SSIM, guard PSNR)."""
    out = []
    for m, (p, s, g) in (("shipped", shipped), ("F12", f12)):
        scenes = {"procedural": {"psnr": p, "ssim": s}}
        scenes.update({c: {"psnr": g, "ssim": 0.9} for c in GUARD_COLUMNS})
        out.append({"method": m, "scenes": scenes})
    return out


def test_an_entry_is_the_standing_rule_with_the_guard():
    e = entry(table((25.0, 0.700, 27.0), (25.2, 0.710, 27.0)), 3, 3000, "sha256:abc")
    assert e["winner"] == "F12" and e["block"] == 3 and e["iteration"] == 3000
    assert e["shipped"] == {"psnr": 25.0, "ssim": 0.7, "guard_psnr": 27.0} and e["shipped_weights"] == "sha256:abc"
    # higher SSIM but the fixed scenes drop more than 0.3 dB: the shipped model stays
    assert entry(table((25.0, 0.700, 27.0), (25.2, 0.710, 26.6)), 3, 3000)["winner"] == "shipped"
    # lower SSIM
    assert entry(table((25.0, 0.700, 27.0), (25.4, 0.699, 27.0)), 3, 3000)["winner"] == "shipped"


def test_an_entry_scores_f12_before_the_block_only():
    t = table((25.0, 0.7, 27.0), (25.2, 0.71, 27.0))
    with pytest.raises(RuleError, match="not 3500"):
        entry(t, 3, 3500)
    with pytest.raises(RuleError, match="block 0"):
        entry(t, 0, 0)
    with pytest.raises(RuleError, match="'F12' is not in the table"):
        entry(t[:1], 3, 3000)


def test_f12_ships_after_two_consecutive_blocks():
    e = lambda k, w: {"block": k, "iteration": 1000 * k, "winner": w}  # noqa: E731
    assert ships([e(1, "F12"), e(2, "shipped"), e(3, "F12")]) is None
    assert ships([e(1, "F12"), e(2, "F12")]) == 2000
    assert ships([e(1, "F12"), e(2, "F12"), e(3, "shipped"), e(4, "F12"), e(5, "F12")]) == 5000
    assert ships([e(2, "F12"), e(4, "F12")]) is None  # a gap (block 3 unscored) is not consecutive


def test_the_ledger_records_each_block_once_in_order(tmp_path):
    path = str(tmp_path / "ledger.json")
    assert load(path) == []
    win = table((25.0, 0.700, 27.0), (25.2, 0.710, 27.0))
    record(path, entry(win, 2, 2000))
    record(path, entry(table((25.0, 0.700, 27.0), (25.0, 0.690, 27.0)), 1, 1000))
    assert [e["block"] for e in load(path)] == [1, 2] and json.load(open(path))["ships_at"] is None
    record(path, entry(win, 1, 1000))  # a rerun of block 1 replaces its entry
    doc = json.load(open(path))
    assert [e["winner"] for e in doc["blocks"]] == ["F12", "F12"] and doc["ships_at"] == 2000
    (tmp_path / "bad.json").write_text('{"blocks": [{"no": 1}]}')
    with pytest.raises(RuleError, match="bad.json"):
        load(str(tmp_path / "bad.json"))


def test_the_command_line_records_and_names_bad_input(tmp_path, capsys):
    t = tmp_path / "preq.json"
    t.write_text(json.dumps(table((25.0, 0.700, 27.0), (25.2, 0.710, 27.0))))
    ledger = tmp_path / "ledger.json"
    assert main([str(ledger), str(t), "--block", "1", "--iteration", "1000"]) == 0
    assert "winner: F12" in capsys.readouterr().out and load(str(ledger))[0]["block"] == 1
    assert main([str(ledger), str(t), "--block", "2", "--iteration", "1000"]) == 2
    assert "not 1000" in capsys.readouterr().err
    assert main([str(ledger), str(tmp_path / "missing.json"), "--block", "2", "--iteration", "2000"]) == 2


def challenger_table(challenger):
    """The test table with the challenger's row named `challenger`."""
    t = table((25.0, 0.700, 27.0), (25.2, 0.710, 27.0))
    for row in t:
        if row["method"] == "F12":
            row["method"] = challenger
    return t


@pytest.mark.parametrize(
    "challenger,first,run,registered",
    [("F13", 9, "ssr-s46-F13", "Forty-sixth"), ("F14", 12, "ssr-s50-F14", "Fiftieth")],
)
def test_a_rolling_run_has_its_own_row_ledger_and_first_block(tmp_path, challenger, first, run, registered):
    """The challenger names the row, the run recorded in the ledger and the first block it
    may score (F13: 9; F14: 12, the first block F13's ledger has not scored); it ships on
    two consecutive blocks."""
    t = challenger_table(challenger)
    with pytest.raises(RuleError, match=f"starts at block {first}"):
        entry(t, first - 1, 1000 * (first - 1), challenger=challenger)
    path = str(tmp_path / "ledger.json")
    record(path, entry(t, first, 1000 * first, challenger=challenger), challenger=challenger)
    assert json.load(open(path))["ships_at"] is None
    record(path, entry(t, first + 1, 1000 * (first + 1), challenger=challenger), challenger=challenger)
    doc = json.load(open(path))
    assert doc["run"] == run and registered in doc["registered"] and doc["ships_at"] == 1000 * (first + 1)


def test_the_command_names_its_challenger_and_refuses_an_unknown_one(tmp_path, capsys):
    t = challenger_table("F13")
    with pytest.raises(RuleError, match="unknown rolling run 'F15'"):
        entry(t, 9, 9000, challenger="F15")
    tp = tmp_path / "t.json"
    tp.write_text(json.dumps(t))
    assert main([str(tmp_path / "l2.json"), str(tp), "--block", "9", "--iteration", "9000", "--challenger", "F13"]) == 0
    out = capsys.readouterr().out
    assert "F13 at 9000" in out and "winner: F13" in out
