"""``torchhand numerics``: which numeric code paths torchhand's commands use on this machine.

By default every command pins the *portable* profile before torch and NumPy load: AVX2 kernels in torch, MKL's
vendor-independent branch, OpenBLAS's Haswell kernels and NumPy without AVX-512 loops, so that a seed and node
budget give byte-identical result files on any x86-64 CPU with AVX2 (docs/synthesis.md). ``--numerics native`` (or
``TORCHHAND_NUMERICS=native``) keeps the machine's fastest paths instead.

``torchhand numerics --env`` prints the profile's variables as ``export`` lines, for Python programs that call the
API: ``eval "$(torchhand numerics --env)"; python my_script.py`` (or call ``torchhand.reproducible()`` before
importing torch).
"""

from __future__ import annotations

import argparse
import json
import shlex

from .._numerics import describe, portable_env


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("numerics", help="the numeric code paths in use (portable or native), and their variables",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env", action="store_true", help="print the portable profile as shell `export` lines")
    p.add_argument("--json", action="store_true", help="print the profile in use as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    if args.env:
        for key, value in portable_env().items():
            print(f"export {key}={shlex.quote(value)}")
        return 0
    profile = describe()
    if args.json:
        print(json.dumps(profile.as_dict(), indent=2))
        return 0
    print(f"numerics: {profile.mode}")
    print(f"  torch CPU kernels    {profile.torch_capability}")
    print(f"  MKL_CBWR             {profile.mkl_cbwr or '(MKL chooses)'}")
    print(f"  OpenBLAS core type   {', '.join(profile.openblas) or '(not loaded)'}")
    print(f"  NumPy AVX-512 loops  {'on' if profile.numpy_avx512 else 'off'}")
    return 0
