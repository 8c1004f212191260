"""One SHA-256 over the arrays of a result's solution files: what "byte-identical results" is checked with.

The digest covers, for every ``solutions/sol_*.npz`` in name order, each array's name, dtype, shape and bytes (not
the zip container, whose entries carry write times). ``stats.json`` (timings, machine) is not part of it.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from ..errors import MissingFileError


def solutions_digest(result_dir) -> str:
    """Hex SHA-256 of the solution arrays of the result in ``result_dir``; raises MissingFileError without any."""
    files = sorted(Path(result_dir, "solutions").glob("sol_*.npz"))
    if not files:
        raise MissingFileError(f"{result_dir}: no solutions/sol_*.npz to digest")
    h = hashlib.sha256()
    for f in files:
        h.update(f.name.encode())
        with np.load(f, allow_pickle=False) as z:
            for key in sorted(z.files):
                a = np.ascontiguousarray(z[key])
                h.update(f"{key}|{a.dtype.str}|{a.shape}".encode())
                h.update(a.tobytes())
    return h.hexdigest()
