"""The registered decision of issue 11's open runs (weights/README: F6 and F7 of the thirtieth
session, F8 of the thirty-first, F9 of the thirty-fourth, F10 and F11 of the thirty-ninth),
read off one engine-val table by
the standing rule (`ssr.rule`: the procedural column, the fixed scenes as a guard of
0.3 dB), so that the order of the comparisons is code, not prose:

    1. F7 against F6, then the pick against the shipped F5 (the incumbent);
    2. F8 (when the table has it) against that pick;
    3. F9 (when the table has it) against F6: the A/B of the metal brightness term alone;
       if F9 wins it, F9 against the pick of 1-2;
    4. F11 against F10 (when the table has both: the same A/B on the root with procedural
       seeds 0-279), then the pick against the pick of 1-3, which decides what ships.
       Reported beside, deciding nothing: F10 against F6 and F11 against F9 (the same
       settings on 170 more distinct scenes).

    python -m ssr.registered val.json [--json]

val.json is `subpixel eval --table --json` over engine val at 6,000 iterations with the rows
named F5, F6, F7 and, when they have finished, F8, F9, F10 and F11 (`training/registered.sh WORK rules`
makes it). Prints every comparison and the winner; exit status 2 on a table that cannot
decide (a missing row or column).
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import List, Optional, Sequence, Tuple

from .rule import RuleError, judge

COLUMNS = ("procedural",)
GUARD_COLUMNS = ("cbox", "cornell", "cornell-box", "dining-room", "room", "staircase2")
GUARD_DB = 0.3


def compare(table: Sequence[dict], incumbent: str, challenger: str) -> Tuple[str, str]:
    """(winner, one line saying why) of the standing rule with the registrations' columns
    and guard."""
    winner, reason, _, _ = judge(table, incumbent, challenger, COLUMNS, GUARD_COLUMNS, GUARD_DB)
    return winner, f"{challenger} against {incumbent}: {winner} ({reason})"


def pick(table: Sequence[dict]) -> Tuple[str, List[str]]:
    """The registered chain over `table`: (what ships, one line per comparison)."""
    methods = {r.get("method") for r in table}
    steps = []
    first, why = compare(table, "F6", "F7")
    steps.append(why)
    best, why = compare(table, "F5", first)
    steps.append(why)
    if "F8" in methods:
        best, why = compare(table, best, "F8")
        steps.append(why)
    if "F9" in methods:
        ab, why = compare(table, "F6", "F9")
        steps.append(why)
        if ab == "F9" and best != "F9":
            best, why = compare(table, best, "F9")
            steps.append(why)
    if "F10" in methods and "F11" in methods:
        for base, run in (("F6", "F10"), ("F9", "F11")):
            if base in methods:
                steps.append(compare(table, base, run)[1] + " [reported, not deciding]")
        ab, why = compare(table, "F10", "F11")
        steps.append(why)
        if best != ab:
            best, why = compare(table, best, ab)
            steps.append(why)
    return best, steps


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ssr.registered", description=__doc__.split("\n\n")[0])
    ap.add_argument("table", help="JSON of `subpixel eval --table --json` with rows F5, F6, F7[, F8, F9, F10, F11]")
    ap.add_argument("--json", action="store_true", help="print the decision as JSON")
    args = ap.parse_args(argv)
    try:
        table = json.load(open(args.table))
        if not isinstance(table, list):
            raise RuleError("expected the JSON list `subpixel eval --table --json` prints")
        best, steps = pick(table)
    except (OSError, json.JSONDecodeError, RuleError, KeyError, TypeError) as err:
        print(f"error: {args.table}: {err}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps({"winner": best, "steps": steps}, indent=2))
    else:
        print("\n".join(steps))
        print(f"ships: {best}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
