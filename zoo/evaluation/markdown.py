"""The Markdown of evaluator rows, refusing to mix protocols: a result's ``tables.md`` and a
leaderboard's per-protocol tables (each table one protocol, horizons as columns), with each
metric's unit and printed precision and the headline's metric (:func:`headline_key`).
"""

# zoo: computes no number

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
import pandas as pd
from tabulate import tabulate

from zoo.protocol.benchmark import representation_of
from zoo.protocol.comparable import ProtocolMismatchError, check_comparable
from zoo.protocol.metrics import METRICS

# Metrics whose tables print the standard deviation over windows beside the mean.
WITH_STD = tuple(name for name, m in METRICS.items() if m.with_std)


def metric_unit(metric: str) -> tuple[str, str]:
    """Unit and printed precision of ``metric`` (zoo.protocol.metrics.METRICS; unknown: none,
    ``.4g``)."""
    m = METRICS.get(metric)
    return (m.unit, m.fmt) if m else ("", ".4g")


def headline_key(protocol: dict[str, Any]) -> tuple[str, str]:
    """The ``(metric, joints)`` a benchmark's headline reports, as its representation says:
    skeletons, MPJPE under the first (official) joint protocol; meshes, the normalised vertex
    RMSE."""
    return representation_of(protocol).headline(protocol)


def markdown_tables(
    frame: pd.DataFrame,
    records: dict[str, dict[str, Any]],
    horizons_ms: Iterable[int] | None = None,
    headline: str = "",
) -> str:
    """One Markdown table per (metric, averaging, joints), horizons as columns, after the
    ``headline`` table if given."""
    ids = sorted(frame["protocol_id"].unique())
    missing = [i for i in ids if i not in records]
    if missing:
        raise ProtocolMismatchError(f"rows carry protocol ids {missing} with no protocol record")
    check_comparable({i: records[i] for i in ids})
    record = records[ids[0]]
    horizons = list(horizons_ms or default_horizons(frame))
    out = [
        f"# {record['benchmark']}: {record['dataset']} {record['split']}, "
        f"sampler {record['sampler']}, {_frames_text(record)} at {record['fps']:g} fps",
        "",
        f"Protocol {ids[0]}; actions present: {', '.join(record['actions_present'])}; "
        f"{record['action_averaging']}.",
        "",
    ]
    if headline:
        out += [headline, ""]
    # The headline's protocol first (per action), then the others.
    headline_metric, headline_joints = headline_key(record)
    first = (headline_metric, "frame", headline_joints)
    groups = sorted(
        frame.groupby(["metric", "averaging", "joints"], sort=True),
        key=lambda item: item[0] != first,
    )
    order = _action_order(record)
    for (metric, averaging, joints), group in groups:
        group = group[group["horizon_ms"].isin(horizons)]

        table = _pivot(group, "value", horizons, order)
        columns = list(table.columns[2:])  # the horizons, after model and action
        description = record.get("joint_protocols", {}).get(joints, "")
        unit, fmt = metric_unit(metric)
        how = f"{record.get('averaging', {}).get(averaging, '')}. {description}."
        if metric in WITH_STD and "std" in group and group["std"].notna().any():
            spread = _pivot(group, "std", horizons, order)
            table = table.astype(object)
            for column in columns:
                table[column] = [
                    f"{m:{fmt}} ({s:{fmt}})" for m, s in zip(table[column], spread[column])
                ]
            how += " Each cell: mean (standard deviation over windows)."
        out += [
            f"## {metric.upper()} ({unit}), averaging `{averaging}`, joints `{joints}`",
            "",
            how,
            "",
            tabulate(
                table,
                headers=["model", "action"] + [f"{h} ms" for h in columns],
                tablefmt="github",
                floatfmt=fmt,
                showindex=False,
                disable_numparse=metric in WITH_STD,
            ),
            "",
        ]
    return "\n".join(out)


def _pivot(
    group: pd.DataFrame, values: str, horizons: list[int], order: dict[str, int]
) -> pd.DataFrame:
    """``values`` of one table's rows, a row for every model beside every action (blank where a
    model has no row, as pivot_table gives), actions in ``order`` (others after, by name):
    columns ``model``, ``action``, then the horizons. Built from the rows in Python: pandas'
    index operations cost more than the tables they make here (docs/architecture.md)."""
    keys = list(zip(group["model"], group["action"], group["horizon_ms"]))
    cells = dict(zip(keys, group[values].to_numpy(dtype=float)))
    if len(cells) < len(keys):  # a table's ground-truth rows come with each of its results
        keyed = group.set_index(["model", "action", "horizon_ms"])[values]
        cells = keyed.groupby(level=[0, 1, 2], sort=False).mean().to_dict()
    present = {h for _, _, h in keys}
    columns = [h for h in horizons if h in present]
    actions = sorted({a for _, a, _ in keys}, key=lambda a: (order.get(a, len(order) + 1), a))
    rows = [(m, a) for m in sorted({m for m, _, _ in keys}) for a in actions]
    table = {"model": [m for m, _ in rows], "action": [a for _, a in rows]}
    for h in columns:
        table[h] = np.array([cells.get((m, a, h), np.nan) for m, a in rows], dtype=float)
    return pd.DataFrame(table)


def _frames_text(record: dict[str, Any]) -> str:
    """``10 in / 25 out``; a long-term run says how many frames it predicted and in what steps."""
    text = f"{record['input_frames']} in / {record['output_frames']} out"
    if record.get("task") == "longterm":
        text = (
            f"{record['input_frames']} in / {record['predicted_frames']} out "
            f"({record['output_frames']} per step, autoregressive)"
        )
    return text


def default_horizons(frame: pd.DataFrame) -> list[int]:
    """The standard columns up to 1000 ms, then (long-term runs) every 200 ms and the last
    predicted frame."""
    standard = [80, 160, 320, 400, 560, 720, 880, 1000]
    present = set(frame["horizon_ms"])
    chosen = [h for h in standard if h in present]
    if not chosen:
        return sorted(present)
    longer = sorted(h for h in present if h > 1000)
    return chosen + [h for h in longer if h % 200 == 0 or h == longer[-1]]


def _action_order(record: dict[str, Any]) -> dict[str, int]:
    order = {a: i for i, a in enumerate(record.get("actions_present", []))}
    order["average"] = len(order)
    return order
