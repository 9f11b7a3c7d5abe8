"""``zoo site``: the leaderboards as a static site that opens from ``file://``, offline.

Every page is HTML written from Jinja2 templates (autoescaped); each page's data is inlined as
JSON in a ``<script>`` element, and the mesh clips are a script file of their own, so no page
fetches anything. Tables, switches, sorting and charts are one small hand-written script
(``assets/site.js``, SVG drawn from the inlined numbers): one chart library would weigh more
than the whole site's code and still need per-page data. Cards are Markdown rendered by
markdown-it-py, the CommonMark parser of the Python ecosystem."""

from __future__ import annotations

import base64
import json
import re
import shutil
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from zoo.core.errors import ZooError
from zoo.core.io import replace_folder
from zoo.protocol.metrics import FLOOR_SUFFIX
from zoo.report.cards import checkpoint_budget_notes, short_training_notes
from zoo.report.outputs import PALETTE
from zoo.site.collect import (
    Benchmark,
    Table,
    key_horizons,
    read_benchmarks,
    read_models,
)

HERE = Path(__file__).parent
# In every built site: a folder that holds anything else is never replaced.
MARKER = ".zoo-site"
ASSETS = HERE / "assets"


@dataclass
class SiteBuild:
    out: Path
    pages: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def bytes(self) -> int:
        return sum(p.stat().st_size for p in self.out.rglob("*") if p.is_file())


def _environment():
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(HERE / "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.filters["data"] = _script_json
    return env


def _script_json(value: Any) -> str:
    """JSON safe inside a ``<script>`` element (no ``</`` can close it)."""
    from markupsafe import Markup

    text = json.dumps(value, allow_nan=False, separators=(",", ":"))
    return Markup(text.replace("</", "<\\/").replace("<!--", "<\\!--"))


# a card's parts that its page shows itself, from the data (its title, rows and curves)
PAGE_SHOWS = ("Training curve", "Rows", "Citation")


def _card_body(text: str) -> str:
    """A card without what its model page already shows: the title line, and the sections
    :data:`PAGE_SHOWS` (each up to the next section of its level or above)."""
    text = re.sub(r"\A# [^\n]*\n", "", text)
    for title in PAGE_SHOWS:
        text = re.sub(rf"^## {re.escape(title)}\n.*?(?=^## |\Z)", "", text, flags=re.S | re.M)
    return text


def _markdown(text: str, model_pages: set[str], images: dict[str, Path], cards_dir: Path) -> str:
    """A card's Markdown as HTML: links to other cards point at their pages, pictures beside
    the card are copied into the site, any other relative link is kept as text."""
    from markdown_it import MarkdownIt

    # raw HTML in a card stays text: a card can neither run a script nor load from the network;
    # its comments (the generated part's markers) are for its editors, not its readers
    text = re.sub(r"<!--.*?-->", "", text, flags=re.S)
    html = MarkdownIt("commonmark", {"html": False}).enable("table").render(text)

    def link(match: re.Match) -> str:
        target = match.group(1)
        if re.match(r"^[a-z]+:", target) or target.startswith("#"):
            return match.group(0)
        path = Path(target.split("#")[0])
        if path.suffix == ".md" and f"model-{path.stem}.html" in model_pages:
            return f'href="model-{path.stem}.html"'
        return 'data-offsite="' + target + '"'

    def image(match: re.Match) -> str:
        target = match.group(1)
        source = (cards_dir / target).resolve()
        inside = source.is_relative_to(cards_dir.resolve()) and source.is_file()
        if re.match(r"^[a-z]+:", target) or not inside:
            return 'data-src="' + target + '" title="(picture not in the site)"'
        images[f"cards/{source.name}"] = source
        return f'src="cards/{source.name}"'

    html = re.sub(r'href="([^"]*)"', link, html)
    return re.sub(r'src="([^"]*)"', image, html)


def _clips_script(path: Path) -> tuple[str, dict[str, Any]]:
    """The mesh clips as a script (``window.ZOO_CLIPS = {...}``) and what the page says of
    them; positions go as base64 little-endian int16 mm around each window's centre."""
    from zoo.report.clips import Clips

    clips = Clips.read(path)

    def pack(a: np.ndarray, dtype: str = "<i2") -> str:
        return base64.b64encode(np.ascontiguousarray(a, dtype=dtype).tobytes()).decode()

    data = {
        "benchmark": clips.benchmark,
        "fps": clips.fps,
        "input_frames": clips.input_frames,
        "windows": [int(w) for w in clips.windows],
        "sequences": clips.sequences,
        "actions": clips.actions or clips.sequences,
        "vertices": int(clips.truth.shape[2]),
        "frames": int(clips.truth.shape[1]),
        "faces": pack(clips.faces, "<i4"),
        "face_count": int(len(clips.faces)),
        "truth": pack(clips.steps(clips.truth)),
        "models": sorted(clips.predictions),
        "predictions": {k: pack(clips.steps(v)) for k, v in sorted(clips.predictions.items())},
    }
    script = "window.ZOO_CLIPS = " + json.dumps(data, separators=(",", ":")) + ";\n"
    shown = ("windows", "sequences", "actions", "models", "vertices", "fps")
    return script, {
        **{k: data[k] for k in shown},
        "faces": data["face_count"],
        "mesh_vertices": clips.mesh_vertices,
    }


def _for_script(summary: dict[str, Any] | None) -> dict[str, Any] | None:
    """The summary as the page's script reads it: each row with its model's name (``base``:
    no ``@last``, no floor suffix; one colour per model site-wide) and its ``variant``."""
    if summary is None:
        return None
    views = []
    for view in summary["views"]:
        rows = [
            dict(
                row,
                base=_base(row["model"]),
                variant=row["model"].partition("@")[2],
            )
            for row in view["models"]
        ]
        views.append(dict(view, models=rows, key_horizons=key_horizons(view["horizons_ms"])))
    return dict(summary, views=views)


def _base(model: str) -> str:
    return model.partition("@")[0].removesuffix(FLOOR_SUFFIX)


def _cost_rows(table: Table) -> dict[str, dict[str, str]]:
    return {
        m: {
            "parameters": row.get("parameters", ""),
            "gflop": row.get("gflop_per_sample", ""),
            "latency_ms": row.get("latency_ms", ""),
            "train_per_s": row.get("train_samples_per_s", ""),
            "device": row.get("device", ""),
            "date": row.get("date", ""),
        }
        for m, row in table.costs.items()
    }


def _readable_protocol(protocol: dict[str, Any] | None) -> list[tuple[str, Any]]:
    """The protocol record's fields as (name, text) pairs, provenance and file lists left to
    ``protocol.json`` itself."""
    if not protocol:
        return []
    out = []
    for key, value in protocol.items():
        if key in ("provenance", "files"):
            continue
        if isinstance(value, dict):
            value = "; ".join(f"{k}: {v}" for k, v in value.items())
        elif isinstance(value, list):
            value = ", ".join(map(str, value))
        out.append((key.replace("_", " "), value))
    files = protocol.get("files") or []
    if files:
        out.append(("files", f"{len(files)} recordings, each with its sha256 in protocol.json"))
    return out


def _citation(bench: Benchmark, table: Table, version: str) -> str:
    view = table.headline or {}
    return (
        f"motion-zoo {version}, benchmark {bench.name}, table {table.name} "
        f"(protocol {(table.protocol or {}).get('protocol_id', '?')}): "
        f"{str(view.get('metric', '')).upper()} ({view.get('unit', '')}), "
        f"{view.get('averaging', '')} averaging, joints {view.get('joints', '')}"
    )


def build_site(
    out: str | Path,
    results_root: str | Path,
    weights_root: str | Path | None = None,
    cards_dir: str | Path | None = None,
    registry=None,
) -> SiteBuild:
    """Write the site into ``out`` (replaced as a whole): an index, a page per benchmark,
    per table, per model, a comparison page per benchmark and a mesh page per mesh benchmark
    with clips. Problems (a damaged row, a missing card, a table with no rows) are shown on
    their page and returned as warnings."""
    from zoo.core.version import __version__
    from zoo.models.registry import load_registry
    from zoo.paths import REPO_ROOT

    start = time.perf_counter()
    results_root = Path(results_root)
    cards_dir = Path(cards_dir) if cards_dir else REPO_ROOT / "docs" / "models"
    registry = registry or load_registry()
    benchmarks = read_benchmarks(results_root)
    weight_problems: list[str] = []
    models = read_models(registry, cards_dir, weights_root, weight_problems)
    env = _environment()
    build = SiteBuild(Path(out))
    model_pages = {m.page for m in models}
    # registry order, as the leaderboards' PNG plots colour them (zoo.report.outputs.model_style);
    # a row's model outside the registry takes its colour from its letters, there and here
    model_names = registry.list_models()
    common = {
        "version": __version__,
        "benchmarks": benchmarks,
        "models": models,
        "palette_models": model_names,
        "palette_colours": list(PALETTE),
    }
    images: dict[str, Path] = {}
    pages: dict[str, str] = {}
    extra: dict[str, str] = {}
    render = partial(_render, env, common)
    budgets = short_training_notes(
        registry,
        {m.name: m.shipped for m in models},
    )
    # what every model must beat: the registered models that learn nothing
    baselines = [
        n for n in model_names if not registry.get(n).trainable and not registry.get(n).weights_of
    ]
    for bench in benchmarks:
        notes = {label: note for (b, label), note in budgets.items() if b == bench.name}
        for table in bench.tables:  # rows scored from a run of zoo train, not shipped weights
            notes.update(checkpoint_budget_notes(registry, table.runs))
        _benchmark_pages(
            render, bench, model_names, sorted(model_pages), pages, extra, notes, baselines
        )
    for model in models:
        card = (
            _markdown(_card_body(model.card), model_pages, images, cards_dir) if model.card else ""
        )
        pages[model.page] = _model_page(render, model, card, benchmarks, model_names)
    pages["index.html"] = render("index.html", title="motion-zoo", problems=weight_problems)

    for bench in benchmarks:
        build.warnings += bench.problems + [p for t in bench.tables for p in t.problems]
    build.warnings += weight_problems + [p for m in models for p in m.problems]

    with replace_folder(build.out, markers=(MARKER,)) as tmp:
        (tmp / MARKER).write_text("a site written by zoo site; the next build replaces it\n")
        for name, html in pages.items():
            (tmp / name).write_text(html)
        for name, text in extra.items():
            (tmp / name).write_text(text)
        (tmp / "assets").mkdir()
        for asset in sorted(ASSETS.iterdir()):
            shutil.copy2(asset, tmp / "assets" / asset.name)
        for name, source in images.items():
            (tmp / name).parent.mkdir(exist_ok=True)
            shutil.copy2(source, tmp / name)
    build.pages = sorted(pages)
    build.seconds = time.perf_counter() - start
    return build


def _render(env, common: dict, template: str, **context) -> str:
    return env.get_template(template).render(**common, **context)


def _benchmark_pages(
    render, bench, model_names, model_pages, pages: dict, extra: dict, budgets: dict, baselines
) -> None:
    """A benchmark's pages: one per table, its mesh page (with its clips' script), its
    comparisons page and its own page."""
    from zoo.core.version import __version__

    quoted = bench.quoted
    for table in bench.tables:
        pages[table.page] = render(
            "table.html",
            title=f"{bench.name} / {table.name}",
            bench=bench,
            table=table,
            protocol_rows=_readable_protocol(table.protocol),
            baselines=baselines,
            data={
                "summary": _for_script(table.summary),
                "costs": _cost_rows(table),
                "models": model_names,
                "pages": model_pages,
                "budgets": budgets,
                "sources": table.sources,
                "baselines": baselines,
            },
        )
    clips = None
    if bench.clips is not None:
        try:
            script, clips = _clips_script(bench.clips)
        except ZooError as exc:
            bench.problems.append(f"{exc} (zoo site --clips --benchmark {bench.name})")
        else:
            extra[f"clips-{bench.name}.js"] = script
            pages[f"meshes-{bench.name}.html"] = render(
                "meshes.html",
                title=f"{bench.name}: meshes",
                bench=bench,
                clips=clips,
                data={"models": model_names},
            )
    comparisons = [
        (t, t.summary.get("comparisons") or [])
        for t in bench.tables
        if t.summary is not None and t.summary.get("comparisons")
    ]
    if comparisons:
        pages[f"compare-{bench.name}.html"] = render(
            "compare.html", title=f"{bench.name}: comparisons", bench=bench, comparisons=comparisons
        )
    pages[bench.page] = render(
        "benchmark.html",
        title=bench.name,
        bench=bench,
        quoted=quoted,
        citation=_citation(bench, quoted, __version__) if quoted else "",
        clips=clips,
        compare_page=f"compare-{bench.name}.html" if comparisons else None,
    )


def _model_page(render, model, card: str, benchmarks, model_names) -> str:
    """A model's page: its card, its shipped weights' training curves, its rows everywhere."""
    from zoo.hub.weights import training_points

    curves = {}
    for shipped in model.shipped:
        name = f"{shipped.record.benchmark}/{shipped.label}"
        try:
            curves[name] = [[int(s), float(v)] for s, v in training_points(shipped.record)]
        except (KeyError, TypeError, ValueError) as exc:
            model.problems.append(f"{name}: its weights record's training history ({exc!r})")
    return render(
        "model.html",
        title=model.name,
        model=model,
        card=card,
        rows=_model_rows(model.name, benchmarks),
        data={"curves": {k: v for k, v in curves.items() if v}, "models": model_names},
    )


def _model_rows(name: str, benchmarks: list[Benchmark]) -> list[dict[str, Any]]:
    """A model's rows (its own and ``@last``) in every table's headline view."""
    out = []
    for bench in benchmarks:
        for table in bench.tables:
            view = table.headline
            if view is None:
                continue
            for row in view["models"]:
                if _base(row["model"]) != name or row["floor"]:
                    continue
                out.append(
                    {
                        "bench": bench.name,
                        "table": table,
                        "view": view,
                        "row": row,
                    }
                )
    return out
