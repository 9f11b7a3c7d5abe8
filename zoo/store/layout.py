"""Where results go: a result's folder is ``<root>/<benchmark>/<table>/<label>/``
(:func:`table_folder`, :func:`result_path`), its label checked to name a folder
(:func:`check_label`) or made from a run's overridden hyper-parameters (:func:`variant_label`).
The layout: docs/results.md ("What a stored row is").
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path
from typing import Any

from zoo.core.errors import ZooError
from zoo.core.io import canonical_json
from zoo.paths import REPO_ROOT

RESULTS_DIR = REPO_ROOT / "results"
# what the zoo writes beside the benchmarks of a results folder of one's own (zoo cards, zoo
# site): never read as a benchmark
BESIDE_BENCHMARKS = ("cards", "site")


def is_repository_results(results_root: str | Path) -> bool:
    """Whether ``results_root`` is the repository's own results folder (where cards, the README
    and the site are the repository's), not a folder of one's own."""
    return Path(results_root).resolve() == RESULTS_DIR.resolve()


LABEL_PATTERN = r"[A-Za-z0-9_][A-Za-z0-9_.@+=,-]*"


class StoreError(ZooError, ValueError):
    pass


def table_folder(
    sampler: str,
    task: str = "prediction",
    truth: str | None = None,
    horizon: int | None = None,
    melv: str | None = None,
) -> str:
    """The folder under ``<root>/<benchmark>/`` of one sampler, task, ground truth and (when
    not the benchmark's default) MELV frames: ``all``, ``all-completion``, ``all-longterm50``,
    ``all-gt_spectral``, ``all-melv_raw``, ..."""
    folder = sampler if task == "prediction" else f"{sampler}-{task}{horizon or ''}"
    folder = folder if truth in (None, "raw") else f"{folder}-gt_{truth}"
    return folder if melv is None else f"{folder}-melv_{melv}"


def result_path(root: str | Path | None, benchmark: str, table: str, label: str) -> Path:
    return Path(root or RESULTS_DIR) / benchmark / table / check_label(label)


def check_label(label: str) -> str:
    """A row label names a folder: letters, digits and ``_ . @ + = , -``."""
    if not isinstance(label, str) or not re.fullmatch(LABEL_PATTERN, label) or len(label) > 120:
        raise StoreError(
            f"label {label!r}: a label is letters, digits and '_.@+=,-' (at most "
            f"120, not starting with '.', '-' or another sign); it names the "
            f"result folder"
        )
    return label


def variant_label(name: str, overrides: dict[str, Any]) -> str:
    """The default label of a run with overridden hyper-parameters: ``name+key=value,...``
    (never the plain model's label), or ``name+<hash>`` when the values do not fit a name."""
    if not overrides:
        return name
    parts = ",".join(f"{k}={_compact(v)}" for k, v in sorted(overrides.items()))
    label = f"{name}+{parts}"
    if re.fullmatch(LABEL_PATTERN, label) and len(label) <= 80:
        return label
    return f"{name}+{hashlib.sha256(canonical_json(overrides).encode()).hexdigest()[:8]}"


def _compact(value: Any) -> str:
    return value if isinstance(value, str) else json.dumps(value, separators=(",", ":"))
