"""What the site shows, read from the committed files: per benchmark its tables
(``summary.json``, ``protocol.json``, ``efficiency.csv`` beside each ``leaderboard.md``), its
mesh clips, and per model its card and the records of its shipped weights. Nothing here
computes a number: every value is one a leaderboard rebuild stored. What cannot be read is
kept as a problem, which the page it belongs to shows and ``zoo site`` warns about."""

from __future__ import annotations

import csv
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from zoo.evaluation.results import TABLE_FILE, table_files, table_labels
from zoo.paths import REPO_ROOT
from zoo.store.layout import BESIDE_BENCHMARKS, RESULTS_DIR

if TYPE_CHECKING:  # the cards import pandas: a site that only reads tables does not need it
    from zoo.report.cards import Shipped

SUMMARY_FILE = "summary.json"


@dataclass
class Table:
    benchmark: str
    name: str
    protocol: dict[str, Any] | None = None
    summary: dict[str, Any] | None = None
    costs: dict[str, dict[str, str]] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    sources: dict[str, dict[str, str]] = field(default_factory=dict)  # per row: see row_source
    runs: dict[str, dict[str, Any]] = field(default_factory=dict)  # a checkpoint row's provenance

    @property
    def page(self) -> str:
        return f"table-{self.benchmark}-{self.name}.html"

    @property
    def protocol_id(self) -> str:
        return str((self.protocol or {}).get("protocol_id", "(unknown)"))

    @property
    def quoted(self) -> bool:
        """The table a paper quotes: the benchmark's own sampler, scored against the ground
        truth as stored (not a reconstruction of it)."""
        p = self.protocol or {}
        return p.get("ground_truth", "raw") == "raw" and self.name == p.get("sampler")

    @property
    def headline(self) -> dict[str, Any] | None:
        views = (self.summary or {}).get("views") or []
        return next((v for v in views if v.get("headline")), None)

    def leaders(self) -> list[dict[str, Any]]:
        """Per horizon of the headline view, what the table shows on load: the lowest of its
        rows (no ``@last`` row, no floor or other unranked row) and how many of them are bold
        (not distinguishable from the table's best), so the index says no more than the table
        does."""
        view = self.headline
        if view is None:
            return []
        rows = [
            m
            for m in view["models"]
            if "@last" not in m["model"] and not m.get("floor") and not m.get("unranked")
        ]
        out = []
        for i in key_horizons(view["horizons_ms"]):
            horizon = view["horizons_ms"][i]
            valued = [m for m in rows if m["values"][i] is not None]
            best = min(valued, key=lambda m: m["values"][i], default=None)
            bold = sum(1 for m in valued if (m.get("bold") or [False] * (i + 1))[i])
            out.append(
                {
                    "horizon_ms": horizon,
                    "model": best["model"] if best else None,
                    "value": best["values"][i] if best else None,
                    "bold": bold,
                    "rows": len(valued),
                }
            )
        return out


@dataclass
class Benchmark:
    name: str
    tables: list[Table]
    clips: Path | None = None
    problems: list[str] = field(default_factory=list)
    about: str = ""  # what the benchmark is: its YAML's opening comment

    @property
    def quoted(self) -> Table | None:
        readable = [t for t in self.tables if t.headline is not None]
        return next((t for t in readable if t.quoted), readable[0] if readable else None)

    @property
    def page(self) -> str:
        return f"bench-{self.name}.html"


@dataclass
class Model:
    name: str
    card: str | None  # Markdown
    description: str
    shipped: list[Shipped] = field(default_factory=list)  # its weights files and records
    problems: list[str] = field(default_factory=list)
    training: str | None = None  # a trainable model without shipped weights: where it stands
    representation: tuple[str, ...] = ()  # the benchmarks it is scored on: joints, mesh
    kind: str = ""  # trained (it learns), baseline (it learns nothing)
    paper_url: str = ""  # its paper (arXiv, DOI or open archive) and its authors' code
    code_url: str = ""
    bibtex: str = ""

    @property
    def page(self) -> str:
        return f"model-{self.name}.html"


def _no_nan(word: str):
    raise ValueError(f"{word} is no number JSON has")


def _read_json(path: Path, problems: list[str], what: str) -> dict[str, Any] | None:
    try:
        value = json.loads(path.read_text(), parse_constant=_no_nan)
        if not isinstance(value, dict):
            raise ValueError(f"a JSON {type(value).__name__}, not an object")
        return value
    except FileNotFoundError:
        problems.append(f"{path}: missing ({what})")
    except (OSError, ValueError) as exc:
        problems.append(f"{path}: not readable JSON ({what}): {exc}")
    return None


def _costs(folder: Path, problems: list[str]) -> dict[str, dict[str, str]]:
    path = folder / "efficiency.csv"
    if not path.is_file():
        return {}
    try:
        with open(path, newline="") as f:
            return {row["model"]: row for row in csv.DictReader(f)}
    except (OSError, KeyError, csv.Error) as exc:
        problems.append(f"{path}: not a readable cost table: {exc}")
        return {}


# What the pages read of a summary.json (zoo.report.tables.table_summary), level by level.
_VIEW_KEYS = (
    "metric",
    "averaging",
    "joints",
    "headline",
    "unit",
    "format",
    "horizons_ms",
    "averaging_words",
    "joints_words",
    "interval_words",
    "best",
    "models",
    "reported",
    "other_protocols",
)
_ROW_KEYS = (
    "model",
    "floor",
    "unranked",
    "values",
    "half",
    "bold",
    "per_action",
    "curve",
)
_COMPARISON_KEYS = ("a", "b", "metric", "joints", "averaging", "kind", "units", "design", "rows")
_COMPARISON_ROW_KEYS = (
    "horizon_ms",
    "a",
    "b",
    "difference",
    "lo",
    "hi",
    "a_lower",
    "units",
    "sign_p",
    "verdict",
)


def summary_fault(summary: dict[str, Any]) -> str | None:
    """Where ``summary`` is not what :func:`zoo.report.tables.table_summary` writes, in words (None
    where it is)."""

    def missing(item, keys, where: str) -> str | None:
        if not isinstance(item, dict):
            return f"{where} is not an object"
        absent = [k for k in keys if k not in item]
        return f"{where} has no {', '.join(absent)}" if absent else None

    views = summary.get("views")
    if not isinstance(views, list):
        return "no list of views"
    for i, view in enumerate(views):
        fault = missing(view, _VIEW_KEYS, f"views[{i}]")
        if fault:
            return fault
        width = len(view["horizons_ms"])
        if len(view["best"]) != width:
            return f"views[{i}].best does not have one model per horizon"
        for j, row in enumerate(view["models"]):
            where = f"views[{i}].models[{j}]"
            fault = missing(row, _ROW_KEYS, where)
            if fault:
                return fault
            # "lowest" since 2026-12: a table written before has "bold" alone
            lengths = ("values", "bold") + (("lowest",) if "lowest" in row else ())
            for key in lengths + (("half",) if row["half"] is not None else ()):
                if not isinstance(row[key], list) or len(row[key]) != width:
                    return f"{where}.{key} does not have one entry per horizon"
    for i, pair in enumerate(summary.get("comparisons") or []):
        fault = missing(pair, _COMPARISON_KEYS, f"comparisons[{i}]")
        for j, row in enumerate(pair.get("rows") or [] if not fault else []):
            fault = fault or missing(row, _COMPARISON_ROW_KEYS, f"comparisons[{i}].rows[{j}]")
        if fault:
            return fault
    return None


def row_provenance(folder: Path) -> dict[str, Any]:
    """A row's provenance, from its ``protocol.json`` (empty where it cannot be read)."""
    try:
        return json.loads((folder / "protocol.json").read_text()).get("provenance") or {}
    except (OSError, ValueError):
        return {}


def row_source(folder: Path, benchmark: str, protocol: dict[str, Any]) -> dict[str, str]:
    """Where a row's numbers come from, from its ``protocol.json``: when and at which code
    version they were computed, and the command that computes them again from the shipped
    weights (none for a row without them, whose command is its own registry's)."""
    provenance = row_provenance(folder)
    if not provenance:
        return {}
    weights, sampler = provenance.get("weights"), protocol.get("sampler")
    model = provenance.get("model") or folder.name
    # a results folder of one's own: its commands run from anywhere (the repository's own run
    # from the clone, as its README says)
    own_folder = not folder.resolve().is_relative_to(RESULTS_DIR.resolve())
    if weights and own_folder and not Path(weights).is_absolute():
        weights = str(REPO_ROOT / weights)
    options = [f"--weights {weights}" if weights else f"--model {model}"]
    registry = str(provenance.get("registry") or "")
    if registry.startswith("outside:"):  # a researcher's registry, named by its file alone
        options += ["--registry", registry.removeprefix("outside:")]
    options += ["--benchmark", benchmark, "--sampler", str(sampler)]
    if own_folder:
        options += ["--out", str(folder.resolve())]
    task = protocol.get("task", "prediction")
    if task != "prediction":
        options += ["--task", task]
        if task == "longterm":
            options += ["--horizon-frames", str(protocol.get("predicted_frames"))]
    truth = str(protocol.get("ground_truth") or "raw")
    if truth != "raw":  # spectral256: the CLI's --ground-truth spectral
        options += ["--ground-truth", re.sub(r"\d+$", "", truth)]
    source = {
        "created": str(provenance.get("created", ""))[:10],
        "code": str(provenance.get("code_version", "")),
        "command": "zoo eval " + " ".join(options),
    }
    if weights is None and provenance.get("training"):
        source["command"] = ""  # a checkpoint's row: not from shipped weights
    imported = provenance.get("imported") or {}
    if imported and not imported.get("redistributable"):
        source["needs"] = (
            "first make its weights, which their licence keeps out of the repository: "
            "zoo weights import of the files their record names (zoo leaderboard --check "
            "--results on this table names them and the command)"
        )
    return source


def read_table(benchmark: str, folder: Path) -> Table:
    table = Table(benchmark, folder.name)
    table.protocol = _read_json(folder / "protocol.json", table.problems, "the table's protocol")
    table.summary = _read_json(
        folder / SUMMARY_FILE,
        table.problems,
        f"the table as data; zoo leaderboard --benchmark {benchmark} writes it",
    )
    fault = summary_fault(table.summary) if table.summary is not None else None
    if fault:
        table.problems.append(
            f"{folder / SUMMARY_FILE}: not the table as data that zoo leaderboard writes "
            f"({fault}); zoo leaderboard --benchmark {benchmark} rewrites it"
        )
        table.summary = None
    elif table.summary is not None and not table.summary["views"]:
        table.problems.append(f"{folder / SUMMARY_FILE}: the table has no rows")
    if table.protocol is not None:
        try:
            labels = table_labels(folder)
        except Exception as exc:  # the table's own message names the file and the fix
            table.problems.append(str(exc))
        else:
            for label in labels:
                if not (folder / label / "results.csv").is_file():
                    table.problems.append(
                        f"{folder / label / 'results.csv'}: missing (a row the table lists)"
                    )
                source = row_source(folder / label, benchmark, table.protocol)
                if source:
                    table.sources[label] = source
                provenance = row_provenance(folder / label)
                if "checkpoint" in provenance:
                    table.runs[label] = provenance
    table.costs = _costs(folder, table.problems)
    return table


def key_horizons(horizons: list[int]) -> list[int]:
    """The horizons a table shows on load, as indices: the first, the one nearest 400 ms and
    the last (the page's script reads them from each view)."""
    middle = min(range(len(horizons)), key=lambda i: abs(horizons[i] - 400))
    return sorted({0, middle, len(horizons) - 1})


def benchmark_about(name: str) -> str:
    """A benchmark's own words for what it is: the opening comment of its YAML file (up to the
    first blank comment line), or "" where there is none."""
    from zoo.protocol.benchmark import BENCHMARK_DIR

    path = BENCHMARK_DIR / f"{name}.yaml"
    lines = []
    for line in path.read_text().splitlines() if path.is_file() else []:
        if not line.startswith("#") or not line.strip("# "):
            break
        lines.append(line.lstrip("#").strip())
    return " ".join(lines)


def read_benchmarks(results_root: Path) -> list[Benchmark]:
    out = []
    for bench_dir in sorted(
        p
        for p in results_root.iterdir()
        if p.is_dir() and not p.name.startswith(".") and p.name not in BESIDE_BENCHMARKS
    ):
        folders = [t.parent for t in table_files(bench_dir)]
        bench = Benchmark(bench_dir.name, [read_table(bench_dir.name, f) for f in folders])
        bench.about = benchmark_about(bench_dir.name)
        if not bench.tables:
            bench.problems.append(f"{bench_dir}: no table ({TABLE_FILE}) in any folder")
        clips = bench_dir / "clips.npz"
        bench.clips = clips if clips.is_file() else None
        out.append(bench)
    return out


def read_models(
    registry, cards_dir: Path, weights_root: Path | None, problems: list[str]
) -> list[Model]:
    """Every registered model with a card or shipped weights; a model with weights and no
    card keeps a problem that says how to write it; weights records that cannot be read go to
    ``problems``."""
    from zoo.core.errors import ZooError
    from zoo.hub.weights import unshipped_models
    from zoo.report.cards import shipped_weights

    readable = True
    try:
        shipped = shipped_weights(weights_root)
    except (ZooError, KeyError, TypeError, ValueError) as exc:
        where = weights_root or "weights/"
        problems.append(f"{where}: the shipped weights' records cannot be read ({exc})")
        shipped, readable = {}, False
    try:  # no status where the records could not be read: "no weights" would be untrue
        own = {m for m, files in shipped.items() if any(f.record.imported is None for f in files)}
        unshipped = unshipped_models(registry, weights_root, own) if readable else {}
    except (ZooError, KeyError, TypeError, ValueError) as exc:
        problems.append(f"{weights_root or 'weights/'}: paused trainings cannot be read ({exc})")
        unshipped = {}
    out = []
    for name in registry.list_models():
        entry = registry.get(name)
        files = shipped.get(entry.weights_of or name, [])
        card_path = cards_dir / f"{name}.md"
        card = card_path.read_text() if card_path.is_file() else None
        if card is None and not files:
            continue
        model = Model(
            name,
            card,
            " ".join(str(getattr(entry, "description", "") or "").split()),
            files,
            training=unshipped.get(name),
            representation=_benchmark_kinds(entry.representation),
            kind="trained" if entry.trainable or entry.weights_of else "baseline",
            paper_url=entry.paper.url if entry.paper else "",
            code_url=entry.code,
            bibtex=entry.paper.bibtex() if entry.paper else "",
        )
        if card is None:
            model.problems.append(f"{card_path}: missing (the model's card); zoo cards writes it")
        out.append(model)
    return out


def _benchmark_kinds(words) -> tuple[str, ...]:
    """The kinds of benchmark a model of registry ``representation`` ``words`` is scored on
    (an ``expmap`` model: joints benchmarks), which the site's model filter shows it under."""
    from zoo.protocol.benchmark import REPRESENTATIONS

    return tuple(r.name for r in REPRESENTATIONS.values() if {r.name, *r.model_kinds} & set(words))
