"""A registry model built for a benchmark: how it sees the benchmark (its view: joints or mesh)
and its constructor keywords, the benchmark's inputs (shape arguments and the context its entry
names) under the entry's hyper-parameters and a caller's overrides. The one place these meet:
the Python API, a row's model source, the training loop and a trained model's record build
through it."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def benchmark_inputs(
    bench, entry, *, data_root: str | Path | None = None, dataset=None
) -> tuple[str, dict[str, Any]]:
    """``(view, inputs)``: how ``entry``'s model sees ``bench``, and the constructor keywords
    the benchmark supplies it (read from ``dataset`` where given, else loaded)."""
    view = bench.view_for(entry.representation)
    return view, bench.model_inputs(entry.context, data_root, dataset, view)


def model_args_for(
    registry,
    name: str,
    bench,
    *,
    data_root: str | Path | None = None,
    dataset=None,
    overrides: dict[str, Any] | None = None,
) -> tuple[str, dict[str, Any]]:
    """``(view, keywords)``: the full constructor keywords of registry model ``name`` on
    ``bench``: its registry defaults, the benchmark's inputs, then ``overrides``."""
    view, inputs = benchmark_inputs(bench, registry.get(name), data_root=data_root, dataset=dataset)
    return view, registry.model_args(name, **{**inputs, **(overrides or {})})
