"""``torchhand plot RESULT_DIR [--out DIR]``: PNG plots of a result directory (matplotlib, no display needed).

Writes into DIR (default RESULT_DIR/plots):
  contact_timeline.png  per finger: free (no contact), static, or sliding (the solution's stored contact_sliding),
                        over time, for --solution
  forces.png            per finger: normal and tangential contact-force magnitudes with the friction-cone limit
                        mu * f_n, for --solution
  joints.png            the flexion joints of each finger over time, the chosen --solutions overlaid
                        (two hands: joints_right.png and joints_left.png)

On a `torchhand manipulate` result (stats.json method "liu2009") contact_timeline.png and forces.png are per hand
contact instead (docs/manipulation.md), and it adds:
  torque_deviation.png  per frame |u - u_bar|^2: the wrist rows, the finger joints and each finger; --compare OTHER
                        overlays a second manipulate result (e.g. the --no-objective ablation) dashed
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import InputValueError
from ._common import add_threads_argument, apply_threads


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plot", help="PNG plots of a result directory: contact timeline, forces, joint trajectories "
                                    "(and the torque deviation of a manipulate result)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("result", metavar="RESULT_DIR", help="output directory of `torchhand synthesize`, `manipulate`, ...")
    p.add_argument("--out", help="directory for the PNG files (created; default RESULT_DIR/plots)")
    p.add_argument("--solution", type=int, default=0, help="solution for the contact and force plots (default 0)")
    p.add_argument("--solutions", default="all", help="solutions overlaid in joints.png: 0,1,2 or all (default all, "
                                                      "at most 8)")
    p.add_argument("--compare", metavar="OTHER_DIR",
                   help="manipulate results only: a second manipulate result overlaid on torque_deviation.png "
                        "(e.g. the same motion with --no-objective)")
    add_threads_argument(p)
    p.set_defaults(func=run)


def run(args) -> int:
    apply_threads(args.threads)
    from torchhand.manipulation.plots import is_manipulation_result, write_plots
    from torchhand.render.jobs import plot_result

    out = Path(args.out) if args.out else Path(args.result) / "plots"
    manipulation = is_manipulation_result(args.result)
    if args.compare is not None:
        if not manipulation:
            raise InputValueError(f"--compare: only for manipulate results; {args.result} is not one (stats.json "
                                  f"method 'liu2009')")
        if not is_manipulation_result(args.compare):
            raise InputValueError(f"--compare {args.compare}: not a manipulate result directory (stats.json method "
                                  f"'liu2009')")
    written = plot_result(args.result, out, solution=args.solution, solutions=args.solutions)
    if manipulation:        # the per-contact plots replace the per-finger contact_timeline.png and forces.png
        mine = write_plots(args.result, out, compare=args.compare)
        written = [p for p in written if p.name not in {m.name for m in mine}] + mine
    print("wrote " + ", ".join(str(p) for p in written))
    return 0
