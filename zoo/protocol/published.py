"""Published figures (``zoo/protocol/published.yaml``) beside measured rows, never mixed with them:
a figure is a ``reported`` row of a table only where its protocol matches the table's record; any
other is listed under its own heading with every difference named."""

# zoo: computes no number

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

from zoo.core.errors import ZooError
from zoo.core.io import load_yaml

PUBLISHED_FILE = Path(__file__).with_name("published.yaml")
FIELDS = ("label", "model", "source", "benchmark", "metric", "averaging", "joints", "protocol")


class PublishedError(ZooError, ValueError):
    pass


@dataclass(frozen=True)  # shared by every reader of the same file's text (load_published)
class Published:
    label: str
    model: str
    source: str
    benchmark: str
    metric: str
    averaging: str
    joints: str
    protocol: dict[str, Any]
    per_action: dict[str, dict[int, float]] | None = None
    average: dict[int, float] | None = None
    differs: str | None = None


@dataclass
class Placed:
    """A published entry as one table sees it: its figures averaged over the table's actions
    (``values``) where it matches, or the differences that keep it out."""

    entry: Published
    values: dict[int, float]
    differences: list[str]


def load_published(path: str | Path = PUBLISHED_FILE) -> list[Published]:
    """The entries of a published-figures file; its text parsed once per process while it
    stays the same (a rebuild reads it for every table it writes)."""
    return list(_parsed(str(path), Path(path).read_text()))


@lru_cache(maxsize=4)
def _parsed(path: str, text: str) -> tuple[Published, ...]:
    entries = load_yaml(text) or []
    if not isinstance(entries, list):
        raise PublishedError(f"{path}: expected a list of entries, got {type(entries).__name__}")
    out = []
    for i, entry in enumerate(entries):
        label = entry.get("label", "?") if isinstance(entry, dict) else repr(entry)
        where = f"{path}: entry {i + 1} ({label})"
        if not isinstance(entry, dict):
            raise PublishedError(f"{where}: expected a mapping")
        missing = [f for f in FIELDS if f not in entry]
        unknown = sorted(set(entry) - set(FIELDS) - {"per_action", "average", "differs"})
        if missing or unknown:
            raise PublishedError(
                f"{where}: missing {missing}, unknown {unknown}; fields: "
                f"{', '.join(FIELDS)}, per_action or average, differs"
            )
        if ("per_action" in entry) == ("average" in entry):
            raise PublishedError(f"{where}: give exactly one of per_action and average")
        try:
            per_action = (
                {
                    str(a): {int(h): float(v) for h, v in values.items()}
                    for a, values in entry["per_action"].items()
                }
                if "per_action" in entry
                else None
            )
            average = (
                {int(h): float(v) for h, v in entry["average"].items()}
                if "average" in entry
                else None
            )
        except (AttributeError, TypeError, ValueError) as exc:
            raise PublishedError(
                f"{where}: figures must map horizons (ms) to numbers ({exc})"
            ) from exc
        out.append(
            Published(
                **{f: entry[f] for f in FIELDS},
                per_action=per_action,
                average=average,
                differs=entry.get("differs"),
            )
        )
    return tuple(out)


def place(
    record: dict[str, Any],
    metric: str,
    averaging: str,
    joints: str,
    entries: list[Published] | None = None,
) -> list[Placed]:
    """Every published entry of ``record``'s benchmark, as the headline table of that record
    (``metric``, ``averaging``, ``joints``) sees it."""
    entries = load_published() if entries is None else entries
    placed = []
    for entry in entries:
        if entry.benchmark != record.get("benchmark"):
            continue
        differences = [
            f"{key}: {value!r} published, {record.get(key)!r} here"
            for key, value in entry.protocol.items()
            if record.get(key) != value
        ]
        for key, mine in (("metric", metric), ("averaging", averaging), ("joints", joints)):
            if getattr(entry, key) != mine:
                differences.append(f"{key}: {getattr(entry, key)} published, {mine} here")
        if entry.differs:
            differences.append(" ".join(entry.differs.split()))
        values = dict(entry.average or {})  # the entry's own dict is every reader's
        if entry.per_action is not None:
            actions = list(record.get("actions_present", []))
            absent = [a for a in actions if a not in entry.per_action]
            if absent:
                differences.append(f"no published figure for {', '.join(absent)}")
                values = {}
            else:
                common = set.intersection(*(set(entry.per_action[a]) for a in actions))
                values = {
                    h: sum(entry.per_action[a][h] for a in actions) / len(actions)
                    for h in sorted(common)
                }
        placed.append(Placed(entry, values, differences))
    return placed
