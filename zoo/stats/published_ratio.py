"""A measured row against a published figure of the same protocol: per action and horizon, the
row's error over the published one. Published figures carry no per-window errors, so no interval
can be drawn; the ratios say how far a re-trained model lies from the figure it reproduces.

    from zoo.stats.published_ratio import against_published
    r = against_published("results/cmu/all/ltd", "ltd (reported, all windows)",
                          actions=["basketball", "jumping", "running", "soccer", "walking"])
    print(r.markdown())
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path

import pandas as pd
from tabulate import tabulate

from zoo.core.errors import ZooError
from zoo.evaluation.results import EvalResult
from zoo.protocol.published import Published, load_published, place


class PublishedRatioError(ZooError, ValueError):
    pass


def published_entry(
    label: str, benchmark: str | None = None, entries: list[Published] | None = None
) -> Published | None:
    """The published entry labelled ``label`` (of ``benchmark`` where given: one label may name
    a paper's figure on several benchmarks), or None where there is none."""
    found = [
        e
        for e in (load_published() if entries is None else entries)
        if e.label == label and benchmark in (None, e.benchmark)
    ]
    if len(found) > 1:
        raise PublishedRatioError(
            f"{label!r} is published for {', '.join(e.benchmark for e in found)}: give --benchmark"
        )
    return found[0] if found else None


@dataclass
class PublishedRatios:
    """``table``: one row per action (and ``mean``, the mean error over ``actions`` of each,
    divided) with ``measured``, ``published`` and ``ratio`` per horizon as columns
    ``(quantity, horizon_ms)``; ``worst``: per horizon, the action of ``actions`` with the
    largest ratio."""

    row: str
    entry: Published
    actions: list[str]
    horizons_ms: list[int]
    table: pd.DataFrame = field(repr=False)
    where: str = ""  # the table the row was read from, in words

    def ratio(self, action: str = "mean") -> dict[int, float]:
        return {h: float(self.table.loc[action, ("ratio", h)]) for h in self.horizons_ms}

    def worst(self) -> dict[int, tuple[str, float]]:
        ratios = self.table.loc[self.actions, "ratio"]
        return {h: (str(ratios[h].idxmax()), float(ratios[h].max())) for h in self.horizons_ms}

    def markdown(self) -> str:
        e = self.entry
        hs = self.horizons_ms
        rows = [
            [action, *(f"{self.table.loc[action, ('ratio', h)]:.2f}" for h in hs)]
            for action in self.table.index
        ]
        worst = self.worst()
        rows.append(["worst of those", *(f"{worst[h][0]} {worst[h][1]:.2f}" for h in hs)])
        figures = [
            [
                action,
                *(
                    f"{self.table.loc[action, ('measured', h)]:.2f} / "
                    f"{self.table.loc[action, ('published', h)]:.2f}"
                    for h in hs
                ),
            ]
            for action in self.table.index
        ]
        headers = ["action", *(f"{h} ms" for h in hs)]
        return "\n".join(
            [
                f"# {self.row} against {e.label}",
                "",
                f"{self.where}{e.metric}, {e.averaging} averaging, {e.joints}; published: "
                f"{e.source}. "
                f"Ratio = {self.row}'s error / the published one; `mean` divides the two "
                f"means over {', '.join(self.actions)}. Published figures hold no per-window "
                f"errors, so there is no interval.",
                "",
                tabulate(rows, headers=headers, tablefmt="github", disable_numparse=True),
                "",
                f"Errors ({self.row} / published):",
                "",
                tabulate(figures, headers=headers, tablefmt="github", disable_numparse=True),
                "",
            ]
        )


def against_published(
    result: EvalResult | str | Path,
    entry: Published | str,
    *,
    actions: Iterable[str] | None = None,
) -> PublishedRatios:
    """``result``'s figures (a result or its folder) over ``entry``'s (a published entry or its
    label), per action; ``actions`` (default: every action both have) are the ones the mean and
    the worst action cover. Refused where the protocols differ, as a table would refuse to show
    the figure beside the row."""
    if not isinstance(result, EvalResult):
        if not (Path(result) / "results.csv").is_file():
            raise PublishedRatioError(f"{result}: no evaluation here (results.csv missing)")
        result = EvalResult.read(result)
    if result.frame.empty:
        raise PublishedRatioError("the result holds no rows")
    row = str(result.frame["model"].iloc[0])
    record = result.protocol
    if isinstance(entry, str):
        found = published_entry(entry, record.get("benchmark"))
        if found is None:
            raise PublishedRatioError(
                f"no published figure labelled {entry!r} for {record.get('benchmark')}"
            )
        entry = found
    if entry.per_action is None:
        raise PublishedRatioError(
            f"{entry.label!r} publishes an average only; a ratio per action needs per-action "
            f"figures"
        )
    if entry.benchmark != record.get("benchmark"):
        raise PublishedRatioError(
            f"refusing to divide {row} by {entry.label!r}: benchmark {entry.benchmark} "
            f"published, {record.get('benchmark')} here"
        )
    # the protocol as a table would compare it; the actions are chosen below
    (placed,) = place(
        record,
        entry.metric,
        entry.averaging,
        entry.joints,
        entries=[replace(entry, per_action=None, average={})],
    )
    if placed.differences:
        raise PublishedRatioError(
            f"refusing to divide {row} by {entry.label!r}: " + "; ".join(placed.differences)
        )
    frame = result.frame
    frame = frame[
        (frame["metric"] == entry.metric)
        & (frame["averaging"] == entry.averaging)
        & (frame["joints"] == entry.joints)
    ]
    if frame.empty:
        raise PublishedRatioError(
            f"{row} has no {entry.metric} rows with {entry.averaging} averaging on joints "
            f"{entry.joints}, which {entry.label!r} publishes"
        )
    common = [a for a in record.get("actions_present", []) if a in entry.per_action]
    wanted = list(dict.fromkeys(actions)) if actions is not None else common
    unknown = [a for a in wanted if a not in common]
    if unknown or not wanted:
        raise PublishedRatioError(
            f"actions {unknown or wanted}: expected actions that both {row} and "
            f"{entry.label!r} have ({', '.join(common) or 'none'})"
        )
    shared = set.intersection(*(set(entry.per_action[a]) for a in common))
    hs = sorted(h for h in shared if h in set(frame["horizon_ms"]))
    if not hs:
        raise PublishedRatioError(f"{row} and {entry.label!r} share no horizon")
    measured = frame.pivot_table(index="action", columns="horizon_ms", values="value")
    measured = measured.reindex(index=common, columns=hs)
    if measured.isna().any().any():
        gaps = [f"{a} at {h} ms" for a in common for h in hs if pd.isna(measured.loc[a, h])]
        raise PublishedRatioError(f"{row} has no figure for {', '.join(gaps[:5])}")
    published = pd.DataFrame({h: {a: entry.per_action[a][h] for a in common} for h in hs})
    measured.loc["mean"] = measured.loc[wanted].mean()
    published.loc["mean"] = published.loc[wanted].mean()
    table = pd.concat(
        {"measured": measured, "published": published, "ratio": measured / published}, axis=1
    )
    where = f"{record['benchmark']}, sampler {record.get('sampler')}: "
    return PublishedRatios(row, entry, wanted, hs, table, where)
