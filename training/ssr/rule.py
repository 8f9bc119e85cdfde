"""The standing selection rule of the training rounds (weights/README.md), applied to the
scores `subpixel eval --table --json` prints, so that a registered rule is read off the
same numbers every time instead of by eye:

    subpixel eval --table --json --pred PRED --ref DATASET --split val > val.json
    python -m ssr.rule val.json --incumbent F1t16e --challenger F3 [--columns procedural]
        [--guard-columns cbox,cornell,... --guard-db 0.3]

The challenger is picked over the incumbent when its SSIM is higher and its PSNR is at
least the incumbent's minus the margin (0.05 dB); otherwise the incumbent stays. Both are
read from the mean over the chosen scene columns (default: every column of the table, the
table's `mean`). With a guard, the challenger must also keep the mean PSNR of the guard
columns no more than `--guard-db` below the incumbent's. Exit status 0 either way; the
decision is printed (and with --json written as JSON).
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Dict, List, Optional, Sequence, Tuple

MARGIN_DB = 0.05
"""How much PSNR the challenger may give up for a higher SSIM."""


class RuleError(ValueError):
    """A table that cannot decide: a missing method or column, or a column a method lacks."""


def column_means(table: Sequence[dict], method: str, columns: Optional[Sequence[str]] = None) -> Tuple[float, float]:
    """(PSNR, SSIM) of `method`: the mean over `columns` (default: all of the table's scene
    columns) of its per-column means, as the table's `mean` column."""
    rows = [r for r in table if r.get("method") == method]
    if not rows:
        names = ", ".join(sorted(str(r.get("method")) for r in table))
        raise RuleError(f"method '{method}' is not in the table (methods: {names})")
    scenes: Dict[str, dict] = rows[0].get("scenes", {})
    cols = list(columns) if columns else sorted({c for r in table for c in r.get("scenes", {})})
    if not cols:
        raise RuleError("the table has no scene columns")
    missing = [c for c in cols if c not in scenes]
    if missing:
        raise RuleError(f"method '{method}' has no score in column(s) {', '.join(missing)}")
    psnr = sum(float(scenes[c]["psnr"]) for c in cols) / len(cols)
    ssim = sum(float(scenes[c]["ssim"]) for c in cols) / len(cols)
    return psnr, ssim


def decide(
    incumbent: Tuple[float, float], challenger: Tuple[float, float], margin: float = MARGIN_DB
) -> Tuple[bool, str]:
    """(challenger picked, reason) for (PSNR, SSIM) pairs under the standing rule."""
    (pi, si), (pc, sc) = incumbent, challenger
    if not sc > si:
        return False, f"SSIM {sc:.4f} not above {si:.4f}"
    if pc < pi - margin:
        return False, f"SSIM {sc:.4f} above {si:.4f} but PSNR {pc:.2f} below {pi:.2f} - {margin:g}"
    return True, f"SSIM {sc:.4f} above {si:.4f} and PSNR {pc:.2f} not below {pi:.2f} - {margin:g}"


def guard(incumbent_psnr: float, challenger_psnr: float, max_drop_db: float) -> Tuple[bool, str]:
    """(passed, reason): the challenger's guard-column PSNR at most `max_drop_db` below."""
    ok = challenger_psnr >= incumbent_psnr - max_drop_db
    word = "not more" if ok else "more"
    return ok, f"guard PSNR {challenger_psnr:.2f} {word} than {max_drop_db:g} dB below {incumbent_psnr:.2f}"


def judge(
    table: Sequence[dict],
    incumbent: str,
    challenger: str,
    columns: Optional[Sequence[str]] = None,
    guard_columns: Optional[Sequence[str]] = None,
    guard_db: float = 0.3,
    margin: float = MARGIN_DB,
) -> Tuple[str, str, Tuple[float, float], Tuple[float, float]]:
    """The standing rule on `table`: (winner, reason, incumbent's and challenger's (PSNR,
    SSIM) over `columns`), the guard applied when `guard_columns` are given. RuleError for
    a missing method or column."""
    inc = column_means(table, incumbent, columns)
    cha = column_means(table, challenger, columns)
    g = None
    if guard_columns:
        g = column_means(table, incumbent, guard_columns)[0], column_means(table, challenger, guard_columns)[0]
    picked, reason = decide(inc, cha, margin)
    if picked and g:
        picked, why = guard(g[0], g[1], guard_db)
        reason = f"{reason}; {why}"
    return (challenger if picked else incumbent), reason, inc, cha


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ssr.rule", description=__doc__.split("\n\n")[0])
    ap.add_argument("table", help="JSON of `subpixel eval --table --json` ('-' for stdin)")
    ap.add_argument("--incumbent", required=True, help="the method that stays unless the challenger wins")
    ap.add_argument("--challenger", required=True)
    ap.add_argument("--columns", default=None, help="comma-separated scene columns to average (default: all)")
    ap.add_argument("--margin", type=float, default=MARGIN_DB, help="PSNR the challenger may give up (dB)")
    ap.add_argument("--guard-columns", default=None, help="comma-separated columns whose mean PSNR may not drop much")
    ap.add_argument("--guard-db", type=float, default=0.3, help="how far the guard columns' PSNR may drop (dB)")
    ap.add_argument("--json", action="store_true", help="print the decision as JSON")
    args = ap.parse_args(argv)
    try:
        text = sys.stdin.read() if args.table == "-" else open(args.table).read()
        table = json.loads(text)
        if not isinstance(table, list):
            raise RuleError(f"{args.table}: expected the JSON list `subpixel eval --table --json` prints")
        cols = [c for c in args.columns.split(",") if c] if args.columns else None
        gcols = [c for c in args.guard_columns.split(",") if c] if args.guard_columns else None
        winner, reason, inc, cha = judge(table, args.incumbent, args.challenger, cols, gcols, args.guard_db, args.margin)
    except (OSError, json.JSONDecodeError, RuleError, KeyError, TypeError) as err:
        print(f"error: {args.table}: {err}", file=sys.stderr)
        return 2
    over = ", ".join(cols) if cols else "every column"
    if args.json:
        out = {
            "winner": winner,
            "reason": reason,
            "columns": cols or "all",
            **({"guard_columns": gcols, "guard_db": args.guard_db} if gcols else {}),
            args.incumbent: {"psnr": inc[0], "ssim": inc[1]},
            args.challenger: {"psnr": cha[0], "ssim": cha[1]},
        }
        print(json.dumps(out, indent=2))
    else:
        print(f"{args.incumbent}: {inc[0]:.2f} / {inc[1]:.4f}; {args.challenger}: {cha[0]:.2f} / {cha[1]:.4f} (mean over {over})")
        print(f"winner: {winner} ({reason})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
