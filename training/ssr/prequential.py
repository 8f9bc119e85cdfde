"""The prequential ledger of a rolling run (weights/README: F12 of the "Forty-second
session", withdrawn in the forty-sixth; F13 of the "Forty-sixth session", paused in the
fiftieth; F14 of the "Fiftieth session"): before the run
trains on block K it is scored on that block's sequences, which no model has seen, against
the shipped model, and the standing rule (`ssr.rule`, with the columns and guard of
`ssr.registered`) decides between the two. The ledger (a JSON file committed as
`weights/prequential-RUN.json`) holds one entry a block; the run ships when the rule picks
it on two consecutive blocks, at the later block's iteration:

    python -m ssr.prequential LEDGER --block K --iteration N TABLE [--challenger F13] [--json]

TABLE is `subpixel eval --table --json --split train` over the block's scoring root with
the rows `shipped` and the run's (`training/registered.sh WORK prequential K` makes it).
The entry for K is written (replacing an earlier one for K, e.g. a rerun); the decision and
whether the run now ships are printed. Exit status 2 on a table or ledger that cannot
decide.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import List, Optional, Sequence

from .registered import COLUMNS, GUARD_COLUMNS, GUARD_DB
from .rule import RuleError, column_means, judge

INCUMBENT = "shipped"
CHALLENGER = "F12"
"""The default challenger (the ledger's first run)."""
F5 = "weights/baselines/ssr-s29-F5.safetensors"
ROLLING = {
    "F12": {
        "run": "ssr-s42-F12",
        "registered": "weights/README.md, Forty-second session",
        "first_block": 1,
        "start": {"weights": F5, "iteration": 0, "what": "F5 as shipped from the twenty-ninth session",
                  "base": F5, "base_iterations": 0},
        "recipe": "block K trains iterations 1,000K to 1,000(K+1) of 30,000 on block K alone (ds-block-K), "
                  "F9's options (F6's with --lambda mm=5), lr 1.25e-4 halved at 10,000 and 20,000, "
                  "one core (training/registered.sh WORK F12 K)",
    },
    "F13": {
        "run": "ssr-s46-F13",
        "registered": "weights/README.md, Forty-sixth session",
        "first_block": 9,
        "start": {"weights": "weights/baselines/ssr-s46-P46.safetensors", "iteration": 8000,
                  "what": "P46: F5 continued 1,000 iterations on blocks 1-7 at once (ds-upto-7), lr 3.125e-5",
                  "base": F5, "base_iterations": 1000},
        "recipe": "block K trains iterations 1,000K to 1,000(K+1) of 30,000 on blocks 1 to K at once "
                  "(ds-upto-K), F6's options with lr 3.125e-5 halved at 10,000 and 20,000, "
                  "model config emission background, one core (training/registered.sh WORK F13 K)",
    },
    "F14": {
        "run": "ssr-s50-F14",
        "registered": "weights/README.md, Fiftieth session",
        "first_block": 12,
        "start": {"weights": "weights/baselines/ssr-s46-P46.safetensors", "iteration": 8000,
                  "what": "P46 (F5 continued 1,000 iterations on blocks 1-7 at once), then F13's iterations 8,000 "
                          "to 11,250 on 512-spp blocks (F14 begins from F13's whole checkpoint at 11,250, "
                          "weights/restore/ssr-s46-F13-it0011250.pt)",
                  "base": F5, "base_iterations": 1000},
        "recipe": "F13's from 11,250 with the blocks it trains on rendered at 32 spp: block K trains iterations "
                  "1,000K to 1,000(K+1) of 30,000 on blocks 1 to K at once at 32 spp (ds-spp32-upto-K), "
                  "--min-reference-psnr 0, F6's options with lr 3.125e-5 halved at 10,000 and 20,000, model "
                  "config emission background, one core (training/registered.sh WORK F14 K); scored on the "
                  "512-spp blocks",
    },
}
"""The rolling runs: run folder, registration, the first block their ledger scores (F12
at block 0 is its start, F5; F13's block 8 is where P46's score was seen before it was
registered; F14's first is the first block F13 has not scored), their start (its weights,
the run's iteration there, and the shipped model it was trained from with the iterations
between) and their recipe, which `ssr.ship` writes into the provenance of weights it
ships."""
BLOCK_ITERATIONS = 1000
"""Iterations a block trains (block K: iterations 1,000K to 1,000(K+1))."""


def rolling(challenger: str) -> dict:
    """The registration of rolling run `challenger`, or RuleError naming the known ones."""
    if challenger not in ROLLING:
        raise RuleError(f"unknown rolling run {challenger!r} (expected one of {', '.join(ROLLING)})")
    return ROLLING[challenger]


def entry(
    table: Sequence[dict], block: int, iteration: int, shipped: Optional[str] = None, challenger: str = CHALLENGER
) -> dict:
    """Block `block`'s ledger entry: both rows' figures and the rule's decision, the rolling
    run `challenger` at `iteration` (which must be the block's first, 1,000K: the weights
    before the block); `shipped` names the incumbent's weights (e.g. their SHA-256),
    recorded as given."""
    first = rolling(challenger)["first_block"]
    if block < first:
        raise RuleError(f"block {block}: {challenger}'s scoring starts at block {first}")
    if iteration != BLOCK_ITERATIONS * block:
        raise RuleError(
            f"block {block} scores {challenger} at iteration {BLOCK_ITERATIONS * block} (before it trains on the block), "
            f"not {iteration}"
        )
    winner, reason, inc, cha = judge(table, INCUMBENT, challenger, COLUMNS, GUARD_COLUMNS, GUARD_DB)
    figures = {}
    for method, (psnr, ssim) in ((INCUMBENT, inc), (challenger, cha)):
        figures[method] = {
            "psnr": round(psnr, 4),
            "ssim": round(ssim, 5),
            "guard_psnr": round(column_means(table, method, GUARD_COLUMNS)[0], 4),
        }
    named = {"shipped_weights": shipped} if shipped else {}
    return {"block": block, "iteration": iteration, **named, "winner": winner, "reason": reason, **figures}


def ships(entries: Sequence[dict], challenger: str = CHALLENGER) -> Optional[int]:
    """The iteration of the rolling run that ships by the registration: the later of the
    latest two consecutive blocks the rule gave to it, or None. Entries are read in block
    order."""
    won = {e["block"]: e for e in entries if e.get("winner") == challenger}
    best = None
    for k in sorted(won):
        if k - 1 in won:
            best = won[k]["iteration"]
    return best


def load_ledger(path: str) -> dict:
    """The whole ledger at `path` (its run, `ships_at` and entries), or RuleError naming the
    file; a file that does not exist yet is an empty ledger."""
    if not os.path.exists(path):
        return {"blocks": []}
    try:
        with open(path) as f:
            data = json.load(f)
    except (OSError, json.JSONDecodeError) as err:
        raise RuleError(f"{path}: cannot read the ledger ({err})") from None
    entries = data.get("blocks") if isinstance(data, dict) else None
    if not isinstance(entries, list) or not all(isinstance(e, dict) and isinstance(e.get("block"), int) for e in entries):
        raise RuleError(f"{path}: expected {{\"blocks\": [{{\"block\": K, ...}}, ...]}}")
    return data


def load(path: str) -> List[dict]:
    """The ledger's entries (none when the file does not exist yet)."""
    return load_ledger(path)["blocks"]


def record(path: str, new: dict, challenger: str = CHALLENGER) -> List[dict]:
    """Writes `new` into the ledger at `path` of rolling run `challenger` (atomically; an
    entry for the same block is replaced) and returns the entries in block order."""
    reg = rolling(challenger)
    entries = [e for e in load(path) if e["block"] != new["block"]] + [new]
    entries.sort(key=lambda e: e["block"])
    doc = {
        "run": reg["run"],
        "registered": reg["registered"],
        "incumbent": INCUMBENT,
        "ships_at": ships(entries, challenger),
        "blocks": entries,
    }
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(doc, f, indent=2)
        f.write("\n")
    os.replace(tmp, path)
    return entries


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ssr.prequential", description=__doc__.split("\n\n")[0])
    ap.add_argument("ledger", help="the ledger JSON (created when absent)")
    ap.add_argument("table", help="JSON of `subpixel eval --table --json --split train` with rows shipped and the run's")
    ap.add_argument("--block", type=int, required=True, help="the block K the table scores")
    ap.add_argument("--iteration", type=int, required=True, help="the run's iteration in the table (1,000K)")
    ap.add_argument("--challenger", default=CHALLENGER, help=f"the rolling run (its row; default {CHALLENGER})")
    ap.add_argument("--shipped", default=None, help="what the shipped row was (recorded in the entry)")
    ap.add_argument("--json", action="store_true", help="print the entry as JSON")
    args = ap.parse_args(argv)
    try:
        with open(args.table) as f:
            table = json.load(f)
        if not isinstance(table, list):
            raise RuleError("expected the JSON list `subpixel eval --table --json` prints")
        new = entry(table, args.block, args.iteration, args.shipped, args.challenger)
        entries = record(args.ledger, new, args.challenger)
    except (OSError, json.JSONDecodeError, RuleError, KeyError, TypeError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    at = ships(entries, args.challenger)
    if args.json:
        print(json.dumps({**new, "ships_at": at}, indent=2))
    else:
        name = args.challenger
        s, c = new[INCUMBENT], new[name]
        print(
            f"block {new['block']}: {INCUMBENT} {s['psnr']:.2f} / {s['ssim']:.4f} (guard {s['guard_psnr']:.2f}), "
            f"{name} at {new['iteration']} {c['psnr']:.2f} / {c['ssim']:.4f} (guard {c['guard_psnr']:.2f})"
        )
        print(f"winner: {new['winner']} ({new['reason']})")
        print(f"{name} ships at iteration {at}" if at is not None else f"{name} does not ship yet (two consecutive blocks needed)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
