"""Print the digest of each result directory's solution arrays (torchhand.io.digest.solutions_digest).

    python scripts/result_digest.py out/box-turn [more results ...]
"""

from __future__ import annotations

import sys

from torchhand.io.digest import solutions_digest

if __name__ == "__main__":
    for path in sys.argv[1:]:
        print(f"{solutions_digest(path)}  {path}")
