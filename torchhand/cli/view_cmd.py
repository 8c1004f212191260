"""``torchhand view RESULT_DIR [--port PORT] [--host HOST] [--solution K|all]``: a result directory in the browser.

Serves an interactive 3-D viewer (viser: a three.js page and a websocket on one port) of the object, the table,
every solution's hands, contacts and force arrows, with a frame slider, play/pause at the result's frame rate and
the checker's pass/fail of every frame. Prints the URL and serves until Ctrl-C.

The host defaults to 127.0.0.1, this machine only. On a remote machine run `ssh -L 8080:localhost:8080 HOST` on
your own computer and open http://localhost:8080 there; --host 0.0.0.0 lets the whole network reach the viewer
(docs/view.md). A port in use, a missing directory or one that is not a result exits 2 with one line.
"""

from __future__ import annotations

import argparse

from ._common import add_threads_argument, apply_threads


def register(sub: argparse._SubParsersAction) -> None:
    from ..view.defaults import DEFAULT_HOST, DEFAULT_PORT

    p = sub.add_parser("view", help="an interactive 3-D viewer of a result directory in the browser",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("result", metavar="RESULT_DIR", help="a result directory (e.g. of `torchhand synthesize`)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT,
                   help=f"port to listen on (default {DEFAULT_PORT}; 0: any free port)")
    p.add_argument("--host", default=DEFAULT_HOST,
                   help=f"address to listen on (default {DEFAULT_HOST}: this machine only; 0.0.0.0: every interface)")
    p.add_argument("--solution", default="all", metavar="K|all",
                   help="the solution shown first: its index (the XXX of sol_XXX) or all (default); the panel's "
                        "dropdown changes it")
    p.add_argument("--no-check", action="store_true", help="do not run the checker (no per-frame verdicts)")
    add_threads_argument(p)
    p.set_defaults(func=run)


def run(args) -> int:
    apply_threads(args.threads)
    from ..view import serve

    handle = serve(args.result, host=args.host, port=args.port, solution=args.solution, check=not args.no_check,
                   block=False)
    n = len(handle.data.solutions)
    print(f"torchhand view: {handle.data.path} ({handle.data.scene}, {n} solution(s), {handle.data.frames} frames "
          f"at {handle.data.fps:g} fps)")
    print(handle.url, flush=True)
    if args.host in ("127.0.0.1", "localhost", "::1"):
        print(f"from another machine: ssh -L {handle.port}:localhost:{handle.port} THIS_HOST, then open "
              f"http://localhost:{handle.port}", flush=True)
    print("Ctrl-C to stop", flush=True)
    handle.wait()
    return 0
