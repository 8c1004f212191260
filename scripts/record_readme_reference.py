"""Write tests/data/readme_box_turn.npz from the output of the README's main command.

    torchhand synthesize box-turn --out out/box-turn
    python scripts/record_readme_reference.py out/box-turn

The reference holds what tests/torchhand/test_numerics.py compares (the same answer, not the same bits): per
solution i, ``q_i`` (float32: the comparison allows 1e-4 rad), ``contact_mask_i``, ``contact_link_i``,
``contact_sliding_i`` and ``env_contact_mask_i``. It prints the digest and node count to record beside it in
docs/synthesis.md and the test. Run it only after an intended change of the search's answer, and say why in the
commit.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from torchhand.io.digest import solutions_digest

ROOT = Path(__file__).resolve().parents[1]

KEYS = ("contact_mask", "contact_link", "contact_sliding", "env_contact_mask")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("result", type=Path, help="output folder of `torchhand synthesize box-turn --out DIR`")
    ap.add_argument("--to", type=Path, default=ROOT / "tests" / "data" / "readme_box_turn.npz")
    args = ap.parse_args(argv)
    stats = json.loads((args.result / "stats.json").read_text())
    if stats.get("scene") not in (None, "box-turn") or stats["numerics"]["mode"] != "portable":
        print(f"record: {args.result} is not a portable-numerics box-turn run", file=sys.stderr)
        return 2
    files = sorted((args.result / "solutions").glob("sol_*.npz"))
    arrays = {}
    for i, f in enumerate(files):
        z = np.load(f)
        arrays[f"q_{i}"] = z["q"].astype(np.float32)
        for k in KEYS:
            arrays[f"{k}_{i}"] = z[k]
    tmp = args.to.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    tmp.replace(args.to)
    print(f"{args.to}: {len(files)} solutions; nodes_tested {stats['nodes_tested']}; "
          f"digest {solutions_digest(args.result)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
