"""``torchhand plot RESULT_DIR --out DIR``: PNG plots of a result directory (matplotlib, no display needed).

Writes into DIR:
  contact_timeline.png  per finger: free (no contact), static, or sliding (the solution's stored contact_sliding),
                        over time, for --solution
  forces.png            per finger: normal and tangential contact-force magnitudes with the friction-cone limit
                        mu * f_n, for --solution
  joints.png            the flexion joints of each finger over time, the chosen --solutions overlaid
                        (two hands: joints_right.png and joints_left.png)
"""

from __future__ import annotations

import argparse
from ._common import add_threads_argument, apply_threads


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plot", help="PNG plots of a result directory: contact timeline, forces, joint trajectories",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("result", metavar="RESULT_DIR", help="output directory of `torchhand synthesize`")
    p.add_argument("--out", required=True, help="directory for the PNG files (created)")
    p.add_argument("--solution", type=int, default=0, help="solution for the contact and force plots (default 0)")
    p.add_argument("--solutions", default="all", help="solutions overlaid in joints.png: 0,1,2 or all (default all, "
                                                      "at most 8)")
    add_threads_argument(p)
    p.set_defaults(func=run)


def run(args) -> int:
    apply_threads(args.threads)
    from torchhand.render.jobs import plot_result

    written = plot_result(args.result, args.out, solution=args.solution, solutions=args.solutions)
    print("wrote " + ", ".join(str(p) for p in written))
    return 0
