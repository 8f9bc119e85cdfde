"""Ships a rolling run's weights by its prequential ledger (`ssr.prequential`): the snapshot
the ledger's `ships_at` names becomes a weights file (normally `weights/ssr.safetensors`)
whose provenance says how it came to be and why it ships, as a finished run's export does:

    python -m ssr.ship LEDGER SNAPSHOT --out weights/ssr.safetensors

SNAPSHOT is the run's weights at `ships_at` (a trainer snapshot, e.g. the committed restore
point `weights/restore/ssr-s46-F13-it0011000.safetensors`). The tensors and config are kept
byte for byte; the provenance gains the run, its registration and recipe, its start (with
the start's own provenance), the campaign's iteration count and the ledger's blocks up to
`ships_at`; the metrics are those blocks' figures. Refused, naming the file, when the ledger
does not ship the run, or the snapshot is another run's or another iteration's.
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import List, Optional

from .export import WeightsError, export_weights, load_weights
from .prequential import BLOCK_ITERATIONS, ROLLING, load_ledger, ships
from .rule import RuleError


def provenance_of(ledger_path: str, snapshot: str, root: str) -> tuple:
    """(model, provenance, metrics) of `snapshot` shipped by the ledger at `ledger_path` (the
    rolling run is the ledger's); `root` is the repository (the registration's paths are
    relative to it)."""
    if not os.path.isfile(ledger_path):
        raise RuleError(f"{ledger_path}: no such ledger")
    doc = load_ledger(ledger_path)
    named = [name for name, r in ROLLING.items() if r["run"] == doc.get("run")]
    if not named:
        known = ", ".join(r["run"] for r in ROLLING.values())
        raise RuleError(f"{ledger_path}: the ledger of run {doc.get('run')!r}, not a rolling run ({known})")
    challenger = named[0]
    reg = ROLLING[challenger]
    at = ships(doc["blocks"], challenger)
    if at is None:
        raise RuleError(f"{ledger_path}: {challenger} does not ship by its ledger (no two consecutive blocks won)")
    model, meta = load_weights(snapshot)
    prov = meta["provenance"]
    if not isinstance(prov, dict):
        raise WeightsError(f"{snapshot}: provenance is not a trained run's ({prov!r})")
    if prov.get("iterations") != at:
        raise WeightsError(f"{snapshot}: weights at iteration {prov.get('iterations')}, the ledger ships {challenger} at {at}")
    origin = os.path.basename(str(prov.get("snapshot_of", "")).rstrip("/"))
    if origin and origin != reg["run"]:
        raise WeightsError(f"{snapshot}: a snapshot of run {origin!r}, not {reg['run']}")
    start = reg["start"]
    _, start_meta = load_weights(os.path.join(root, start["weights"]))
    _, base_meta = load_weights(os.path.join(root, start["base"]))
    base_prov = base_meta["provenance"] if isinstance(base_meta["provenance"], dict) else {}
    campaign = int(base_prov.get("campaign_iterations", 0)) + start["base_iterations"] + at - start["iteration"]
    blocks = [e for e in doc["blocks"] if e["iteration"] <= at]
    provenance = {
        "model": prov.get("model", "ssr"),
        "name": challenger,
        "run": reg["run"],
        "registered": reg["registered"],
        "recipe": reg["recipe"],
        "iterations": at,
        "campaign_iterations": campaign,
        "blocks_trained": list(range(start["iteration"] // BLOCK_ITERATIONS, at // BLOCK_ITERATIONS)),
        "init_at": start["iteration"],
        "init": {
            "weights": start["weights"],
            "what": start["what"],
            "provenance": start_meta["provenance"],
            "base": {"weights": start["base"], "provenance": base_prov},
        },
        "shipped_by": {
            "ledger": os.path.relpath(ledger_path, root),
            "ships_at": at,
            "rule": "the standing rule (ssr.rule via ssr.prequential) picks the run on two consecutive blocks",
        },
    }
    metrics = {
        "split": "prequential (each block's unseen procedural and fixed sequences, before the run trained on it)",
        "blocks": {str(e["block"]): {k: e[k] for k in ("iteration", "winner", challenger, "shipped") if k in e} for e in blocks},
    }
    return model, provenance, metrics


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ssr.ship", description=__doc__.split("\n\n")[0])
    ap.add_argument("ledger", help="the rolling run's ledger (weights/prequential-RUN.json)")
    ap.add_argument("snapshot", help="the run's weights at the ledger's ships_at")
    ap.add_argument("--out", required=True, help="the weights file to write (e.g. weights/ssr.safetensors)")
    ap.add_argument("--root", default=None, help="the repository root (default: the one holding this package)")
    args = ap.parse_args(argv)
    root = args.root or os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    try:
        model, provenance, metrics = provenance_of(args.ledger, args.snapshot, root)
        size = export_weights(model, args.out, provenance, metrics)  # atomic
    except (RuleError, WeightsError, OSError, KeyError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(
        f"wrote {args.out} ({size} bytes): {provenance['name']} at {provenance['iterations']} "
        f"(campaign iteration {provenance['campaign_iterations']}), shipped by {provenance['shipped_by']['ledger']}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
