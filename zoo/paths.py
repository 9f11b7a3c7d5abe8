"""Where the repository is: the one module every other may import for its paths (it imports
nothing of the zoo), so registry, benchmarks, caches and records need not import each other."""

# zoo: computes no number

from __future__ import annotations

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
