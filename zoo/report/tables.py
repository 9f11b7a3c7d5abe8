"""A leaderboard's headline table with its intervals and cost columns, its reading for the
site (:func:`table_view`, :func:`table_summary`), and the words that say what its ± and bold
mean. The per-protocol Markdown beneath it is :mod:`zoo.evaluation.markdown`.
"""

# zoo: computes no number

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from tabulate import tabulate

from zoo.core.errors import ZooError
from zoo.core.io import json_number
from zoo.evaluation.markdown import _action_order, default_horizons, headline_key, metric_unit
from zoo.stats.intervals import block_frames_default
from zoo.stats.ranking import is_floor, unranked_reason


def _pct(x: float) -> str:
    return f"{100 * x:.0f}%"


def interval_words(windows, models: int = 0) -> str:
    """What a table's ± and bold mean, for its design, with the coverage measured for them
    (``zoo/stats/coverage.yaml``, written by ``benchmarks/coverage/coverage.py``)."""
    from zoo.stats.intervals import (
        MIN_SPAN_WINDOWS,
        REPLICATES,
        block_length,
        coverage_record,
        design,
        short_recordings,
    )

    shape = design(windows.sequence, windows.action)
    record = coverage_record()
    if shape.recording_level:
        k = min(shape.recordings.values())
        text = (
            f"± is half the 95% confidence interval of the benchmark mean: a t interval over "
            f"the independent recordings ({shape.counts()}; each recording's windows together)"
        )
        measured = record.get("confidence", {})
        if "cloth_full" in measured:
            c = measured["cloth_full"]
            text += (
                f". Measured coverage: {_pct(c['single'])} for a model's mean, "
                f"{_pct(c['paired'])} for a paired difference ({c['sets']} pseudo test sets of "
                f"{c['recordings']} recordings drawn from cloth_full's 4,000 test recordings)"
            )
        if k < 100 and "synthetic" in measured:
            c = measured["synthetic"]
            text += (
                f"; on synthetic recordings with heavy-tailed recording effects it covered "
                f"{_pct(c['3_per_action'])} with 3 recordings per action and "
                f"{_pct(c['5_per_action'])} with 5"
            )
    else:
        block = block_frames_default(windows)
        blocks = sorted(
            {
                block_length(windows.start[windows.sequence == r], block, windows.window_frames)
                for r in np.unique(windows.sequence)
            }
        )
        text = (
            f"± is half the 95% window-sampling interval: where the number would lie had other "
            f"windows of these same recordings been drawn (studentised circular block bootstrap "
            f"within each recording, blocks of {', '.join(map(str, blocks))} window(s), t "
            f"quantile on the blocks' degrees of freedom, {REPLICATES} replicates, seed 0). It is "
            f"conditional on the recordings ({shape.counts()}) and is not a confidence interval "
            f"for the actions"
        )
        measured = record.get("window_sampling", {})
        if "synthetic" in measured:
            c = measured["synthetic"]
            text += (
                f": on synthetic recordings of CMU's window counts it covered the true mean "
                f"{_pct(c['short_memory']['single'])} of the time with short memory and "
                f"{_pct(c['long_memory']['single'])} with long memory and heavy tails"
            )
        if "cmu_training" in measured:
            c = measured["cmu_training"]
            cover = ", ".join(
                f"{_pct(v)} at {h} ms" for h, v in zip(c["horizons_ms"], c["repeat_last"])
            )
            paired = ", ".join(
                f"{_pct(v)} at {h} ms" for h, v in zip(c["horizons_ms"], c["paired"])
            )
            text += (
                f"; as an interval for other recordings of the same actions (CMU's training "
                f"recordings, one per action scored, the others' mean held out) it covered "
                f"{cover} (repeat_last), and a paired difference {paired}"
            )
        short = short_recordings(windows.sequence, windows.start, windows.window_frames)
        if short:
            listed = [windows.sequences[i] for i in short]
            text += (
                f". {len(listed)} recording(s) span fewer than {MIN_SPAN_WINDOWS} window lengths "
                f"({', '.join(listed[:8])}{', ...' if len(listed) > 8 else ''}): too short for "
                f"blocks to show their variance, their intervals are known to be too narrow"
            )
    if models > 1:
        text += (
            f". **Bold**: the lowest error at that horizon; *italic*: not distinguishable from "
            f"it by one simultaneous comparison of the table's {models} models (max-t over all "
            f"paired differences). A row far above the lowest but with a wide interval can be "
            f"italic where a closer row with a narrow one is plain: the mark is about the "
            f"evidence, not the distance"
        )
        fwe = record.get("bold", {}).get("fwe")
        if fwe is not None:
            text += (
                f"; among equally good models, at least one was wrongly left unmarked in "
                f"{_pct(fwe)} of simulated tables of {record['bold']['models']} (each model's "
                f"paired interval against the data's best, uncorrected: "
                f"{_pct(record['bold']['fwe_unadjusted'])})"
            )
        text += (
            ". Bold guards against every pair at once, so it needs a larger difference than one "
            "pair does: a model can stay bold beside one that `zoo compare A B` separates from it"
        )
    return text


@dataclass
class TableView:
    """One (metric, averaging, joints) of a table at chosen horizons, action average: the
    value of each row (``values``, model x horizon), half its 95% interval where per-window
    errors are stored (``half``), the best predictor per horizon (``best``) and which rows are
    bold (``bold``: the best, or not distinguishable from it,
    :func:`zoo.stats.intervals.best_set`)."""

    metric: str
    averaging: str
    joints: str
    horizons: list[int]
    values: pd.DataFrame
    half: dict[str, np.ndarray]
    best: pd.Series
    tied: dict[tuple[str, int], bool]
    windows: Any  # the table's WindowErrors, None where no row stored them
    contenders: int  # rows with per-window errors that are predictors (bold compares these)
    unranked: dict[str, str]  # rows that are no prediction to rank: why (unranked_reason)

    def is_bold(self, model: str, horizon: int) -> bool:
        """The lowest at ``horizon``, or not distinguishable from it (its set of the best)."""
        if model in self.unranked:
            return False
        return self.tied.get((model, horizon), model == self.best[horizon])

    def is_lowest(self, model: str, horizon: int) -> bool:
        """The lowest error at ``horizon`` (bold in the table; the rest of the best set is
        marked apart, so "lowest" and "not distinguishable from it" are never read as one)."""
        return model not in self.unranked and model == self.best[horizon]


def table_view(
    results: list,
    metric: str,
    averaging: str,
    joints: str,
    horizons_ms: Iterable[int] | None = None,
    frame: pd.DataFrame | None = None,
) -> TableView | None:
    """The :class:`TableView` of ``results`` (one table's rows) for ``metric``, ``averaging``
    and ``joints``; None where no row has that combination. ``frame``: the rows' frames
    concatenated, where the caller has it already."""
    from zoo.protocol.metrics import cumulative_mean
    from zoo.stats.intervals import best_set, interval

    if frame is None:
        frame = pd.concat([r.frame for r in results], ignore_index=True)
    rows = frame[
        (frame["metric"] == metric)
        & (frame["joints"] == joints)
        & (frame["averaging"] == averaging)
        & (frame["action"] == "average")
    ]
    if rows.empty:
        return None
    horizons = [h for h in (horizons_ms or default_horizons(frame)) if h in set(rows.horizon_ms)]
    values = rows.pivot_table(index="model", columns="horizon_ms", values="value")[horizons]
    frame_of = dict(zip(rows["horizon_ms"], rows["frame"]))
    columns = [int(frame_of[h]) - 1 for h in horizons]  # 0-based predicted frame of each

    def per_window(e: np.ndarray) -> np.ndarray:
        e = e.astype(np.float64)
        return (cumulative_mean(e, axis=1) if averaging == "cumulative" else e)[:, columns]

    # every row of the table that has per-window errors (a model, its autoencoder floor)
    errors = {
        m: per_window(r.windows.get(m, metric, joints))
        for r in results
        if r.windows is not None
        for (m, metric_, joints_) in r.windows.errors
        if metric_ == metric and joints_ == joints and m in values.index
    }
    windows = next((r.windows for r in results if r.windows is not None), None)
    half: dict[str, np.ndarray] = {}
    # An autoencoder floor sees the future, the truth's own MELV is a reference, a held frame's
    # MELV is 0 by construction: none of them is a prediction to rank.
    unranked = {
        m: why for m in values.index if (why := unranked_reason(m, values.loc[m])) is not None
    }
    predictors = [m for m in values.index if m not in unranked]
    best = values.loc[predictors].idxmin() if predictors else values.idxmin()
    tied: dict[tuple[str, int], bool] = {}
    contenders = {m: e for m, e in errors.items() if m not in unranked}
    if windows is not None:
        for m, e in errors.items():
            half[m] = interval(e, windows).half
        if best.isin(list(contenders)).all():
            bold = best_set(contenders, windows)
            tied = {(m, h): bool(bold[m][i]) for m in contenders for i, h in enumerate(horizons)}
    return TableView(
        metric,
        averaging,
        joints,
        horizons,
        values,
        half,
        best,
        tied,
        windows,
        len(contenders),
        unranked,
    )


def view_words(view: TableView, reported: bool) -> str:
    """What a view's ± and bold mean (:func:`interval_words`), what its autoencoder-floor rows
    are, and (``reported``) what its published rows are."""
    if view.windows is None:
        how = "no per-window errors stored, so no intervals"
    else:
        how = interval_words(view.windows, models=view.contenders)

    def named(why: str) -> str:
        return ", ".join(f"`{m}`" for m, w in view.unranked.items() if w == why)

    reasons = set(view.unranked.values())
    if "floor" in reasons:
        how += (
            f". {named('floor')}: the ground-truth future through the model's autoencoder alone "
            f"(it sees the future): the error left with a perfect transformer, a bound, never "
            f"bold"
        )
    if "truth" in reasons:
        how += (
            f". {named('truth')}: the ground truth's own value (how much the real motion "
            f"stretches edges), a reference: unranked, never bold"
        )
    if "zero" in reasons:
        how += (
            f". {named('zero')}: 0 at every horizon by construction (it holds a frame, so every "
            f"edge keeps its length): unranked, never bold"
        )
    if reported:
        how += (
            ". Rows marked (reported) are the papers' figures under this very protocol, "
            "averaged over the actions present here"
        )
    return how


def table_views(
    results: list, horizons_ms: Iterable[int] | None = None, frame: pd.DataFrame | None = None
) -> dict[tuple[str, str, str], TableView]:
    """Every :class:`TableView` of ``results`` (one table's rows), by (metric, averaging,
    joints): computed once for a table's headline and its summary (each view bootstraps
    intervals and draws the bold rule's joint replicates). A caller passing them on passes the
    same ``horizons_ms``. ``frame``: the rows' frames concatenated, where the caller has it."""
    if frame is None:
        frame = pd.concat([r.frame for r in results], ignore_index=True)
    keys = frame[["metric", "averaging", "joints"]].drop_duplicates().itertuples(index=False)
    views = {tuple(k): table_view(results, *k, horizons_ms, frame) for k in keys}
    return {k: v for k, v in views.items() if v is not None}


def table_summary(
    results: list,
    horizons_ms: Iterable[int] | None = None,
    views: dict[tuple[str, str, str], TableView] | None = None,
) -> dict[str, Any]:
    """A table as data (``summary.json`` beside ``leaderboard.md``), for readers other than
    Markdown's: per (metric, averaging, joints), each row's action average at the table's
    horizons with half its interval and whether it is bold, its value per action, its curve over
    every predicted frame, and the published rows of that very protocol. ``views``:
    :func:`table_views` of ``results``, where the caller has them."""
    from zoo.protocol.published import load_published, place

    record = results[0].protocol
    frame = pd.concat([r.frame for r in results], ignore_index=True)
    entries = load_published()  # read once for every view
    metric_h, joints_h = headline_key(record)
    order = _action_order(record)
    computed = table_views(results, horizons_ms, frame) if views is None else views
    histories = history_cells(results)
    summaries = []
    for (metric, averaging, joints), group in frame.groupby(["metric", "averaging", "joints"]):
        view = computed.get((metric, averaging, joints))
        if view is None:
            continue
        horizons = view.horizons
        unit, fmt = metric_unit(metric)
        models = []
        # each mesh row repeats the ground truth's own MELV: one copy of a (model, action, frame)
        group = group.drop_duplicates(["model", "action", "horizon_ms"])
        for m in view.values.index:
            mine = group[group["model"] == m]
            per_action = {
                a: [json_number(v) for v in rows.set_index("horizon_ms")["value"].reindex(horizons)]
                for a, rows in sorted(mine.groupby("action"), key=lambda kv: order.get(kv[0], 0))
                if a != "average"
            }
            curve = mine[mine["action"] == "average"].sort_values("horizon_ms")
            models.append(
                {
                    "model": m,
                    "history": histories.get(m, histories[None]),
                    "floor": is_floor(m),
                    "unranked": m in view.unranked,
                    "values": [json_number(view.values.loc[m, h]) for h in horizons],
                    "half": [json_number(x) for x in view.half[m]] if m in view.half else None,
                    "bold": [view.is_bold(m, h) for h in horizons],
                    "lowest": [view.is_lowest(m, h) for h in horizons],
                    "per_action": per_action,
                    "curve": [
                        [int(h), json_number(v)]
                        for h, v in zip(curve["horizon_ms"], curve["value"])
                    ],
                }
            )
        placed = place(record, metric, averaging, joints, entries)
        summaries.append(
            {
                "metric": metric,
                "averaging": averaging,
                "joints": joints,
                "headline": (metric, averaging, joints) == (metric_h, "frame", joints_h),
                "unit": unit,
                "format": fmt,
                "horizons_ms": horizons,
                "averaging_words": record.get("averaging", {}).get(averaging, ""),
                "joints_words": record.get("joint_protocols", {}).get(joints, ""),
                "interval_words": view_words(view, any(not p.differences for p in placed)),
                "best": [str(view.best[h]) for h in horizons],
                "models": models,
                "reported": [
                    {
                        "label": p.entry.label,
                        "model": p.entry.model,
                        "source": p.entry.source,
                        "values": [p.values.get(h) for h in horizons],
                        "per_action": {
                            a: [p.entry.per_action[a].get(h) for h in horizons]
                            for a in record.get("actions_present", [])
                        }
                        if p.entry.per_action
                        else {},
                    }
                    for p in placed
                    if not p.differences
                ],
                "other_protocols": [
                    {
                        "label": p.entry.label,
                        "source": p.entry.source,
                        "values": {str(h): v for h, v in sorted(p.values.items())},
                        "differences": p.differences,
                    }
                    for p in placed
                    if p.differences
                ],
            }
        )
    summaries.sort(key=lambda v: not v["headline"])
    return {
        "benchmark": record["benchmark"],
        "protocol_id": record["protocol_id"],
        "actions": list(record.get("actions_present", [])),
        "views": summaries,
    }


def headline_table(
    results: list,
    horizons_ms: Iterable[int] | None = None,
    efficiency: dict[str, dict[str, Any]] | None = None,
    published: list | None = None,
    short_training: dict[str, tuple[str, str | None]] | None = None,
    views: dict[tuple[str, str, str], TableView] | None = None,
) -> str:
    """Models as rows, horizons as columns: the benchmark's headline metric (frame averaging,
    action average) with half its 95% interval (:func:`interval_words` says which kind), in bold
    where a model is the best at that horizon or not distinguishable from it (one simultaneous
    comparison of all the table's models, :func:`zoo.stats.intervals.best_set`).

    ``efficiency``: per model, the cost columns ``zoo costs`` stored
    (:mod:`zoo.leaderboard.efficiency`),
    named with the machine that measured them under the table; a model left out of a given
    dict gets empty cost cells and the way to fill them (None: no costs at all). ``published``:
    :func:`zoo.protocol.published.place` of this table (default: from
    ``zoo/protocol/published.yaml``); matching
    figures become ``reported`` rows, the others are listed below with their differences.
    ``short_training``: per row label whose weights were trained short of their recipe, what
    its run saw and a link to its card: the row is marked (†) and the note is under the table.
    ``views``: :func:`table_views` of ``results``, where the caller has them."""
    from zoo.protocol.published import place

    record = results[0].protocol
    metric, joints = headline_key(record)
    if views is None:
        view = table_view(results, metric, "frame", joints, horizons_ms)
    else:
        view = views.get((metric, "frame", joints))
    if view is None:
        return ""
    horizons, values, half = view.horizons, view.values, view.half
    fmt = metric_unit(metric)[1]
    costs, efficiency = efficiency is not None, efficiency or {}
    histories = history_cells(results)
    # shown where some row read other than all the frames given, as they are
    history = [HISTORY_HEADER] if any(h != histories.get(None) for h in histories.values()) else []
    table = []
    for m in values.index:
        cells = []
        for i, h in enumerate(horizons):
            text = f"{values.loc[m, h]:{fmt}}" + (f" ±{half[m][i]:{fmt}}" if m in half else "")
            if view.is_lowest(m, h):
                text = f"**{text}**"
            elif view.is_bold(m, h):
                text = f"*{text}*"
            cells.append(text)
        marked = f"{m} {SHORT_MARK}" if m in (short_training or {}) else m
        read = [histories.get(m, histories[None])] if history else []
        table.append([marked, *cells, *read, *_cost_cells(m, efficiency, costs)])
    placed = place(record, metric, "frame", joints) if published is None else published
    for p in placed:
        if not p.differences:
            table.append(
                [
                    f"{p.entry.label}: {p.entry.source}",
                    *[f"{p.values[h]:{fmt}}" if h in p.values else "–" for h in horizons],
                    *(["–"] if history else []),
                    *_cost_cells(None, {}, False),
                ]
            )
    unit = metric_unit(metric)[0]
    how = view_words(view, any(not p.differences for p in placed))
    out = [
        f"## Headline: {metric.upper()} ({unit}), averaging `frame`, joints `{joints}`, mean "
        f"over actions",
        "",
        how + ".",
        "",
        tabulate(
            table,
            headers=["model"] + [f"{h} ms" for h in horizons] + history + COST_HEADERS,
            tablefmt="github",
            disable_numparse=True,
        ),
    ]
    if costs:
        out += _cost_line(efficiency, record["benchmark"], values.index)
    shown = {m: v for m, v in (short_training or {}).items() if m in values.index}
    if shown:
        out += ["", short_training_line(shown)]
    for p in placed:
        if not p.differences and p.entry.per_action:
            actions = list(record["actions_present"])
            rows = [
                [
                    a,
                    *[
                        f"{p.entry.per_action[a][h]:{fmt}}" if h in p.entry.per_action[a] else "–"
                        for h in horizons
                    ],
                ]
                for a in actions
            ]
            out += [
                "",
                f"### {p.entry.label}: per action ({p.entry.source})",
                "",
                tabulate(
                    rows,
                    headers=["action"] + [f"{h} ms" for h in horizons],
                    tablefmt="github",
                    disable_numparse=True,
                ),
            ]
    others = [p for p in placed if p.differences]
    if others:
        out += ["", "### Published under other protocols (not comparable with the rows above)", ""]
        for p in others:
            figures = ", ".join(f"{h} ms {v:{fmt}}" for h, v in sorted(p.values.items()))
            out.append(
                f"- {p.entry.label}, {p.entry.source}: {figures or 'no average'}; "
                f"differs: {'; '.join(p.differences)}."
            )
    return "\n".join(out)


COST_HEADERS = ["parameters", "GFLOP / window", "latency (ms)", "training windows / s"]
HISTORY_HEADER = "history (frames)"


def history_cells(results: list) -> dict[str | None, str]:
    """Per row label, the observed frames it read: "all 50", "last 10 of 50", or with
    ", padded to 50" where the model lengthened them itself; ``None``: a row that read all."""
    given = results[0].protocol["input_frames"]
    cells: dict[str | None, str] = {None: f"all {given}"}
    for r in results:
        said = (r.protocol.get("provenance") or {}).get("history")
        read = said["read"] if said else given
        text = f"all {given}" if read == given else f"last {read} of {given}"
        if said and said.get("padded_to"):
            text += f", padded to {said['padded_to']}"
        cells.update(dict.fromkeys(r.frame["model"].unique(), text))  # its floor rows too
    return cells


SHORT_MARK = "†"  # a row whose weights were trained short of their recipe


def short_training_line(notes: dict[str, tuple[str, str | None]]) -> str:
    """The paragraph under a headline naming its rows trained short of their recipe."""
    rows: dict[tuple[str, str | None], list[str]] = {}  # rows of one run share its note
    for m, said in sorted(notes.items()):
        rows.setdefault(said, []).append(f"`{m}`")
    parts = [
        f"{', '.join(ms)}: {note}" + (f" ([card]({link}))" if link else "")
        for (note, link), ms in rows.items()
    ]
    return (
        f"{SHORT_MARK} Trained short of its recipe, so not the paper's budget: "
        + "; ".join(parts)
        + "."
    )


# How tables written before ``zoo costs`` named their machine, inside the paragraph above.
_OLD_COST_WORDS = re.compile(
    r"\. Costs measured once per architecture on .*?at the recipe's batch size and precision\)"
)


def _cost_line(efficiency: dict[str, dict[str, Any]], benchmark: str, models) -> list[str]:
    """The paragraph under a headline table (as lines, after a blank one): which machine
    measured its cost columns, and when; how; and how to fill the empty cells of ``models``
    (the table's rows) left out of ``efficiency``."""
    marks = machine_marks(efficiency)
    machines = sorted({_machine(e) for e in efficiency.values()})
    text = ""
    if len(machines) > 1:  # timings of two machines in one column: each cell says whose
        machines = [f"({marks[m]}) {m}" for m in machines]
    if machines:
        text = (
            f"Costs measured by `zoo costs` on {'; '.join(machines)}, every model in "
            f"{' and '.join(sorted({e['precision'] for e in efficiency.values()}))}: "
            f"parameters; forward GFLOPs per window (torch's FlopCounterMode, a multiply-add "
            f"counts 2); median latency of one window (batch 1); training windows per second "
            f"(forward, backward, clip and Adam at the recipe's batch size; fewer latency calls "
            f"and training steps for a slow model, counted in efficiency.csv)."
        )
        if marks:
            text += (
                " Latency and training cells carry their machine's letter: timings of "
                "different machines are not comparable."
            )
    blank = [m for m in models if m not in efficiency and not is_floor(m)]
    if blank:
        text += (
            f"{' ' if text else ''}Empty cost cells ({', '.join(blank)}): no cost stored for "
            f"that model; `zoo costs --benchmark {benchmark}` fills them."
        )
    return ["", text] if text else []


def with_costs(
    markdown: str, models: Iterable[str], efficiency: dict[str, dict[str, Any]], benchmark: str
) -> str:
    """A ``leaderboard.md`` with the cost cells of its headline's ``models`` rows and the
    paragraph under that table as :func:`headline_table` writes them for ``efficiency``, and
    every other byte as it was (``zoo costs`` rewrites costs, nothing else)."""
    lines = markdown.split("\n")
    start = next((i for i, line in enumerate(lines) if line.startswith("## Headline")), None)
    if start is None:
        return markdown
    top = next(i for i in range(start, len(lines)) if lines[i].startswith("| model "))
    end = top
    while end < len(lines) and lines[end].startswith("|"):
        end += 1
    header, *rows = (
        [cell.strip() for cell in line.strip()[1:-1].split("|")]
        for i, line in enumerate(lines[top:end])
        if i != 1  # the rule under the header
    )
    if header[-4:] != COST_HEADERS or any(len(row) != len(header) for row in rows):
        raise ZooError(
            f"a leaderboard.md whose headline has no cost columns where expected "
            f"({' | '.join(header)}); zoo leaderboard --benchmark {benchmark} rewrites it"
        )
    models = set(models)
    rows = [
        row[:-4] + _cost_cells(_label(row[0]), efficiency, True)
        if _label(row[0]) in models
        else row
        for row in rows
    ]
    table = tabulate(rows, headers=header, tablefmt="github", disable_numparse=True).split("\n")
    below = end
    if (
        lines[end : end + 1] == [""]
        and lines[end + 1 : end + 2]
        and (lines[end + 1].startswith(("Costs measured by `zoo costs`", "Empty cost cells")))
    ):
        below = end + 2  # the paragraph this writes
    above = [_OLD_COST_WORDS.sub("", line) for line in lines[start:top]]
    shown = [_label(row[0]) for row in rows if _label(row[0]) in models]
    return "\n".join(
        lines[:start] + above + table + _cost_line(efficiency, benchmark, shown) + lines[below:]
    )


def _label(cell: str) -> str:
    """A headline's model cell without its mark (a reported row's cell is left whole)."""
    return cell.removesuffix(f" {SHORT_MARK}")


def _machine(entry: dict[str, Any]) -> str:
    return f"{entry['device']} ({entry['date']})"


def machine_marks(efficiency: dict[str, dict[str, Any]]) -> dict[str, str]:
    """A letter per machine whose timings ``efficiency`` holds, where there is more than one
    (a column of one machine's timings needs none)."""
    machines = sorted({_machine(e) for e in efficiency.values()})
    return {m: "abcdefghij"[i] for i, m in enumerate(machines)} if len(machines) > 1 else {}


def _cost_cells(model: str | None, efficiency: dict[str, dict[str, Any]], costs: bool) -> list[str]:
    """A row's cost cells: its stored costs; else empty where costs are shown and ``model`` is
    one that ``zoo costs`` measures, "–" where none apply (a floor, a reported row). Timings of
    a table measured on several machines carry their machine's letter (:func:`machine_marks`)."""
    row = efficiency.get(model) if model is not None else None
    if not row:
        return ["" if costs and model is not None and not is_floor(model) else "–"] * 4
    gflop, latency, train = (
        row.get(k) for k in ("gflop_per_sample", "latency_ms", "train_samples_per_s")
    )
    mark = machine_marks(efficiency).get(_machine(row))
    timed = f" ({mark})" if mark else ""
    return [
        f"{row['parameters'] / 1e6:.3f} M" if row["parameters"] else "0",
        "–" if gflop is None else f"{gflop:.3g}",
        "–" if latency is None else f"{latency:.3g}{timed}",
        "–" if train is None else f"{train:.3g}{timed}",
    ]
