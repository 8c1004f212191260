"""Reading a torchhand ``.npz`` input file (capture, grasp, interaction) with one-line errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import FileFormatError, MissingFileError


def read_npz(path, required: tuple[str, ...], what: str) -> dict[str, np.ndarray]:
    """All arrays of ``path`` (no pickles), after checking that the keys in ``required`` are there.

    path: the file; required: keys it must hold; what: the file's kind and its doc for the error messages, such as
        ``"a grasp.npz (docs/manipulation.md)"``
    returns: {key: array}
    raises: MissingFileError (no such file), FileFormatError (not a readable npz, or missing keys, all named)
    """
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"{path}: no such file")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError) as err:
        raise FileFormatError(f"{path}: not a readable .npz file ({err})") from None
    missing = [k for k in required if k not in data]
    if missing:
        raise FileFormatError(f"{path}: missing key(s) {', '.join(missing)}; {what} needs {', '.join(required)}")
    return data
