"""``zoo leaderboard --check``: committed rows recomputed and compared with the committed tables
against :mod:`zoo.evaluation.tolerance`; what was found, per table and overall
(:class:`CheckReport`).

By default a table is checked on a sample of its windows (:func:`draw_sample`: stratified, so
every action has windows in it): every row is recomputed on those windows and each window's
errors compared with the stored ones (``windows.npz``). Every row's ``results.csv`` is also
recomputed exactly from its stored per-window errors, and its identity compared with the one it
records (weights' sha256, protocol and data, hyper-parameters). ``--full`` recomputes every
window. The leaderboard recomputes; this module draws, compares and reports, and writes
nothing."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from zoo.core.budgets import CHECK_WINDOWS
from zoo.evaluation.tolerance import KEY_COLUMNS, agreement, tolerance_by_metric, window_gaps
from zoo.evaluation.tolerance import Incomparable as _Incomparable
from zoo.evaluation.tolerance import allowed as tolerated
from zoo.leaderboard.rounding import INPUT_ULPS, SENSITIVITY_MULTIPLE
from zoo.store.identity import identity_differences, only_code_changed


def draw_sample(actions: np.ndarray, n: int, seed: int) -> np.ndarray:
    """Positions of ``n`` windows (sorted) drawn without replacement from windows of
    ``actions``, stratified: every action gets at least one window (``n`` permitting), the rest
    in proportion to the windows each has left (largest remainders). Every window when ``n``
    covers them."""
    actions = np.asarray(actions)
    if n >= len(actions):
        return np.arange(len(actions))
    names, counts = np.unique(actions, return_counts=True)
    take = np.minimum(counts, 1 if n >= len(names) else 0)
    if n < len(names):  # fewer windows than actions: the largest actions get one each
        take[np.argsort(-counts, kind="stable")[:n]] = 1
    left = n - int(take.sum())
    while left > 0:  # the rest in proportion to the windows not yet taken
        room = counts - take
        quota = left * room / room.sum()
        extra = np.floor(quota).astype(int)
        order = np.argsort(-(quota - extra), kind="stable")
        extra[order[: left - int(extra.sum())]] += 1
        extra = np.minimum(extra, room)
        take += extra
        left = n - int(take.sum())
    rng = np.random.default_rng(seed)
    chosen = [
        rng.choice(np.flatnonzero(actions == name), size=k, replace=False)
        for name, k in zip(names, take)
        if k
    ]
    return np.sort(np.concatenate(chosen))


def fresh_seed() -> int:
    """A sample's seed, drawn anew for each run that is given none."""
    import secrets

    return secrets.randbelow(2**31)


def escape_sentence(n: int, every_action: bool = True) -> str:
    """What a sample of ``n`` windows a row can miss, with the numbers worked out
    (``every_action``: whether each action had windows in every sample)."""
    odds = ", ".join(f"f = {f:.0%}: {(1 - f) ** n:.2g}" for f in (0.01, 0.05, 0.1))
    actions = (
        "; a fault in every window of one action cannot escape (each action is sampled)"
        if every_action
        else "; some actions had no window in a sample (--windows below their number)"
    )
    return (
        f"a fault touching a fraction f of a row's windows escapes a sample of n = {n} of them "
        f"with probability (1 - f)^n ({odds}){actions}; --full checks every window"
    )


@dataclass
class TableCheck:
    """One table's check: its rows (labels), the windows scored of how many (per action), the
    largest difference as a share of its tolerance, its problems, its rows stamped by older
    code and whether the data built here has the bytes each row records."""

    rows: list = field(default_factory=list)
    windows: int = 0
    total: int = 0
    actions: int = 0  # actions among the table's windows
    per_action: dict = field(default_factory=dict)  # windows scored per action
    share: float = 0.0
    problems: list = field(default_factory=list)
    # rows whose weights their licence keeps out of the repository and that are not here: what
    # makes them here (said, and not a problem: nothing committed is wrong)
    needs: list = field(default_factory=list)
    stale: list = field(default_factory=list)  # rows stamped by older code
    data: dict = field(default_factory=dict)  # row -> whether data built here has its bytes
    # values beyond the a-priori tolerance within their measured rounding margin
    # (zoo.leaderboard.rounding):
    # series -> (how many, the largest as a share of the a-priori tolerance)
    rounding: dict = field(default_factory=dict)
    # a full check: the table's windows' actions, and the positions of the windows beyond what
    # they are held to (and beyond the a-priori tolerance alone), for the odds of a sample
    actions_of_windows: np.ndarray | None = None
    beyond: set = field(default_factory=set)
    beyond_a_priori: set = field(default_factory=set)


@dataclass
class CheckReport:
    """What ``zoo leaderboard --check`` found: tables and rows recomputed, on how many windows
    (``windows``: the sample asked for, None: every window; ``seed``: the sample's), the
    largest difference from the committed values (and where), and every problem (a value
    outside its tolerance, a row or table missing on either side, a row that cannot be
    recomputed, weights that are not the recorded ones)."""

    windows: int | None = CHECK_WINDOWS
    seed: int = field(default_factory=fresh_seed)
    largest: tuple = (0.0, 0.0, 0.0, "")  # (share of its tolerance, relative, absolute, where)
    problems: list = field(default_factory=list)
    tables: dict = field(default_factory=dict)  # "<benchmark>/<table>" -> TableCheck
    metrics: set = field(default_factory=set)
    current: str = ""

    def start_table(self, name: str) -> None:
        self.current = name
        self.tables.setdefault(name, TableCheck())

    def sample(self, actions: np.ndarray) -> np.ndarray | None:
        """The windows (positions) the current table is checked on; None: every one."""
        table = self.tables[self.current]
        table.total = len(actions)
        rows = None if self.windows is None else draw_sample(actions, self.windows, self.seed)
        scored = np.asarray(actions) if rows is None else np.asarray(actions)[rows]
        table.windows = len(scored)
        table.actions = len(np.unique(actions))
        table.per_action = dict(zip(*np.unique(scored, return_counts=True)))
        if rows is None:
            table.actions_of_windows = np.asarray(actions)
        return rows

    def problem(self, text: str) -> None:
        """A problem of the table being checked (or of the run, outside any table)."""
        self.problems.append(text)
        if self.current:
            self.tables[self.current].problems.append(text)

    def needs_files(self, text: str) -> None:
        """A row of the current table not checked here: its weights are not shipped."""
        self.tables[self.current].needs.append(text)

    def table_line(self, name: str) -> str:
        """One table: rows, windows (per action) and the largest difference as a share of the
        tolerance, or its problems (the first named)."""
        t = self.tables[name]
        verdict = (
            f"{len(t.problems)} problem(s), first: {t.problems[0]}" if t.problems else "passed"
        )
        if t.total:
            scored = "all" if t.windows == t.total else f"{t.windows} of"
            counts = sorted(t.per_action.values())
            actions = (
                ", ".join(f"{a} {n}" for a, n in t.per_action.items())
                if len(counts) <= 8
                else f"{len(counts)} actions, {counts[0]}-{counts[-1]} each"
            )
            windows = f" on {scored} {t.total} windows ({actions})"
        else:
            windows = ""
        notes = []
        if t.data:
            other = sum(not same for same in t.data.values())
            notes.append(
                f"data built here with other last bits than {other} of its rows record (a "
                f"generated mesh follows the CPU's float kernels; compared within the tolerance)"
                if other
                else "data built here as its rows record (the bytes each was computed or last "
                "verified on)"
            )
        if t.stale:
            notes.append(f"{len(t.stale)} of its rows stamped by older code")
        for text in t.needs:
            notes.append(f"not checked here: {text}")
        if t.rounding:
            notes.append(rounding_note(t.rounding))
        if t.actions_of_windows is not None and (t.beyond or t.beyond_a_priori):
            notes.append(failing_samples(t))
        return (
            f"{name}: {len(t.rows)} rows{windows}, largest difference {t.share:.2f} of the "
            f"tolerance: {verdict}" + "".join(f"; {n}" for n in notes)
        )

    def gap(self, share: float, relative: float, absolute: float, where: str, gap=None):
        """Keep the largest difference (as a share of what it is held to) and where it is; ``gap``
        (a :class:`zoo.evaluation.tolerance.WindowGap`): its values held to their rounding margin
        and its windows beyond the tolerance."""
        if self.current:
            table = self.tables[self.current]
            table.share = max(table.share, share)
            if gap is not None and gap.held_to_rounding:
                table.rounding[where] = (gap.held_to_rounding, gap.a_priori)
            if gap is not None:
                table.beyond |= set(gap.beyond)
                table.beyond_a_priori |= set(gap.beyond_a_priori)
        if share > self.largest[0] or not self.largest[3]:
            self.largest = (share, relative, absolute, where)

    def summary(self) -> list[str]:
        """The closing lines: what was checked, the largest difference, what a sample can
        miss, the tolerances."""
        share, relative, absolute, where = self.largest
        rows = [label for t in self.tables.values() for label in t.rows]
        models = sorted({label.split("@")[0] for label in rows})
        scored = sum(t.windows for t in self.tables.values())
        total = sum(t.total for t in self.tables.values())
        sampled = [t.windows for t in self.tables.values() if t.windows < t.total]
        lines = [
            f"checked {len(rows)} leaderboard rows ({len(models)} models: {', '.join(models)}) "
            f"in {len(self.tables)} tables, on {scored:,} of their {total:,} windows: largest "
            f"difference {absolute:.2g} ({relative:.2g} relative, {share:.2f} of its "
            f"tolerance) at {where or '-'}"
        ]
        if sampled:
            every_action = all(
                len(t.per_action) == t.actions for t in self.tables.values() if t.total
            )
            lines.append(
                f"sample: seed {self.seed} (--seed {self.seed} draws it again); "
                + escape_sentence(min(sampled), every_action)
            )
        stale = sum(len(t.stale) for t in self.tables.values())
        if stale:
            lines.append(
                f"{stale} rows were stamped by older code (the evaluator's, the data's or their "
                f"model's; the same data, protocol, hyper-parameters and weights): their numbers "
                f"were checked as they stand, and zoo leaderboard re-stamps them once a sample "
                f"agrees"
            )
        rounding = {k: v for t in self.tables.values() for k, v in t.rounding.items()}
        if rounding:
            lines.append(
                f"{rounding_note(rounding)}: a model's forward pass rounds otherwise on every "
                f"CPU, and those values moved no more than {SENSITIVITY_MULTIPLE:g} times what "
                f"re-running it here in float64 and on inputs moved by {INPUT_ULPS} units in the "
                f"last place moved them (docs/reproducibility.md)"
            )
        if self.metrics:
            lines.append(f"tolerance: {tolerance_by_metric(self.metrics)}")
        return lines


SAMPLE_SEEDS = 2000  # the seeds over which a full check says how often a sample would fail


def failing_samples(table: TableCheck, seeds: int = SAMPLE_SEEDS) -> str:
    """How many of ``seeds`` sampled checks (:data:`CHECK_WINDOWS` windows each) would hold a
    window beyond what it is held to, and beyond the a-priori tolerance alone: worked out from a
    full check's per-window differences, not by running the checks."""
    beyond = np.zeros(len(table.actions_of_windows), bool)
    beyond[list(table.beyond)] = True
    a_priori = np.zeros_like(beyond)
    a_priori[list(table.beyond_a_priori)] = True
    failed = failed_a_priori = 0
    for seed in range(seeds):
        rows = draw_sample(table.actions_of_windows, CHECK_WINDOWS, seed)
        failed += bool(beyond[rows].any())
        failed_a_priori += bool(a_priori[rows].any())
    return (
        f"a sample of {CHECK_WINDOWS} windows would fail for {failed / seeds:.1%} of seeds "
        f"0-{seeds - 1} ({failed_a_priori / seeds:.1%} against the a-priori tolerance alone)"
    )


def rounding_note(rounding: dict) -> str:
    """Values held to their rounding margin (series -> (count, largest a-priori share))."""
    count = sum(n for n, _ in rounding.values())
    largest = max(share for _, share in rounding.values())
    return (
        f"{count} per-window value(s) in {len(rounding)} series beyond the a-priori tolerance "
        f"(up to {largest:.2f} of it) but within {SENSITIVITY_MULTIPLE:g}x their measured "
        f"rounding sensitivity"
    )


def check_table(
    results: list,
    folder: Path,
    check: CheckReport,
    unplanned: set = frozenset(),
    rows: np.ndarray | None = None,
    margins: dict | None = None,
) -> None:
    """Compare freshly computed results with the committed table in ``folder``: each row's
    per-window errors with its ``windows.npz`` (at positions ``rows``, the sample; None: every
    window, and then its averages with its ``results.csv`` too), and every committed row's
    ``results.csv`` with what its own ``windows.npz`` gives. ``margins``: per row label, the
    rounding margin of its windows beyond the a-priori tolerance
    (:func:`zoo.leaderboard.rounding.rounding_margins`)."""
    from zoo.evaluation.results import TABLE_FILE, WINDOWS_FILE, read_table, table_labels

    name = f"{folder.parent.name}/{folder.name}"
    if not (folder / TABLE_FILE).is_file():
        check.problem(f"{folder}/{TABLE_FILE}: missing; the leaderboard makes this table")
        return
    committed = read_table(folder).frame
    committed = committed[~committed["model"].isin(unplanned)]  # named once, as folders
    check.metrics |= set(committed["metric"])
    recomputed = {str(r.frame["model"].iloc[0]) for r in results}
    for label in table_labels(folder):  # rows not recomputed: their files checked still
        if label not in recomputed and (stored := _read(folder / label, check)) is not None:
            _consistent(stored, folder / label, check)
    for r in results:
        label = str(r.frame["model"].iloc[0])
        path = folder / label / WINDOWS_FILE
        stored = _read(folder / label, check)  # once: its windows, averages and record
        if stored is None:
            continue
        try:
            gaps = window_gaps(r.windows, stored.windows, rows, (margins or {}).get(label))
        except _Incomparable as e:
            check.problem(f"{path}: {e}")
            continue
        for g in gaps:
            where = f"{name}/{label}/{WINDOWS_FILE} {'/'.join(g.key)}"
            check.gap(g.share, g.relative, g.absolute, where, g)
            if g.share > 1:
                widened = g.key in (margins or {}).get(label, {})
                check.problem(
                    f"{path}: {'/'.join(g.key)}: per-window errors differ beyond tolerance "
                    f"(window {g.window}, {stored.windows.action[g.window]}: {g.absolute:.2g} "
                    f"apart, {g.relative:.2g} relative, {g.share:.2f} of the tolerance"
                    + (
                        f" or of {SENSITIVITY_MULTIPLE:g}x its measured rounding sensitivity, "
                        f"whichever is larger)"
                        if widened
                        else ")"
                    )
                )
        _consistent(stored, folder / label, check)
        _data_note(stored.protocol, r.protocol, label, check)
    if rows is None:
        fresh = pd.concat([r.frame for r in results], ignore_index=True)
        _compare_values(fresh, committed, folder, check)


def _place(path: Path) -> str:
    """Where a difference is, short: ``<benchmark>/<table>[/<row>/results.csv]``."""
    parts = path.parts
    return "/".join(parts[-4:] if path.name == "results.csv" else parts[-2:])


def _data_note(stored: dict, fresh: dict, label: str, check: CheckReport) -> None:
    """A generated dataset's bytes (``data_hash``) against those the row was computed on: the
    same, or built with other last bits (another CPU's float kernels), which the per-window
    comparison then judges. A skeleton dataset's files are in the protocol, checked with it."""
    before = data_hash_of(stored)
    now = generated_data_hash(fresh)
    if before is not None and now is not None and check.current:
        check.tables[check.current].data[label] = before == now


def data_hash_of(protocol: dict) -> str | None:
    """The bytes a row's numbers last held on: the data of its latest verification that
    records them (a re-stamp on rebuilt data), else the data it was computed on."""
    provenance = protocol.get("provenance") or {}
    verified = [v["data_hash"] for v in provenance.get("verified") or [] if "data_hash" in v]
    return verified[-1] if verified else provenance.get("data_hash")


def generated_data_hash(protocol: dict) -> str | None:
    """The bytes of the generated data a result (its ``protocol`` record) was computed on (None
    for data read from files, which the protocol names)."""
    return (protocol.get("provenance") or {}).get("data_hash")


def _read(row: Path, check: CheckReport):
    """A committed row (``zoo.evaluation.results.EvalResult``) with its per-window errors, or None
    and a problem where it cannot be read or has none."""
    from zoo.evaluation.results import WINDOWS_FILE, EvalResult

    try:
        stored = EvalResult.read(row)
    except Exception as e:  # noqa: BLE001 - an unreadable row is a problem, the check goes on
        check.problem(f"{row}: not readable: {e}")
        return None
    if stored.windows is None:
        check.problem(f"{row / WINDOWS_FILE}: missing (per-window errors of {row.name})")
        return None
    return stored


def _consistent(stored, row: Path, check: CheckReport) -> None:
    """A committed row's ``results.csv`` against what its own ``windows.npz`` gives, as the
    evaluator sums them (a value edited in one file and not the other is named)."""
    from zoo.evaluation.evaluator import frame_from_windows
    from zoo.evaluation.results import WINDOWS_FILE

    again = frame_from_windows(stored.windows, stored.protocol)
    _compare_values(again, stored.frame, row / "results.csv", check, against=f"its {WINDOWS_FILE}")


def _compare_values(
    fresh: pd.DataFrame, committed: pd.DataFrame, folder: Path, check: CheckReport, against=""
) -> None:
    """Values and standard deviations of ``fresh`` rows against the ``committed`` ones, key by
    key; ``against``: what ``fresh`` was computed from, when not a recomputation."""
    both = fresh.merge(
        committed, on=KEY_COLUMNS, how="outer", suffixes=("", "_committed"), indicator="side"
    )
    source = f", from {against}" if against else ""
    for row in both[both["side"] != "both"].itertuples():
        where = "committed only" if row.side == "right_only" else f"recomputed only{source}"
        check.problem(
            f"{folder}: {where}: " + ", ".join(f"{k}={getattr(row, k)}" for k in KEY_COLUMNS)
        )
    matched = both[both["side"] == "both"]
    for column in ("value", "std"):  # the mean and its standard deviation over windows
        if f"{column}_committed" not in matched:
            check.problem(
                f"{folder}: no column {column!r} (written by an older zoo); regenerate the table"
            )
            continue
        new, old = matched[column].to_numpy(float), matched[f"{column}_committed"].to_numpy(float)
        scale = matched["value_committed"].to_numpy(float)  # a std is held to its mean's
        difference = np.abs(new - old)
        relative = difference / np.maximum(np.abs(old), 1e-12)
        nan = np.isnan(new) | np.isnan(old)  # a NaN (one window's spread) matches only a NaN
        allowed = tolerated(matched["metric"].to_numpy(), scale)
        differs = np.where(nan, np.isnan(new) != np.isnan(old), difference > allowed)
        keep = np.flatnonzero(~nan)
        if keep.size:
            share = difference[keep] / allowed[keep]
            i = keep[int(np.argmax(share))]
            check.gap(
                float(share.max()),
                float(relative[i]),
                float(difference[i]),
                f"{_place(folder)} "
                + ", ".join(f"{k}={matched.iloc[i][k]}" for k in KEY_COLUMNS)
                + f" ({column}{source})",
            )
        for row, rel in zip(matched[differs].itertuples(), relative[differs]):
            check.problem(
                f"{folder}: "
                + ", ".join(f"{k}={getattr(row, k)}" for k in KEY_COLUMNS)
                + f": {column} committed {getattr(row, column + '_committed')!r}, "
                + ("recomputed" if not against else f"{against} gives")
                + f" {getattr(row, column)!r} (relative {rel:.2g}; tolerance "
                f"{tolerance_by_metric([row.metric])})"
            )
    if "protocol_id_committed" in matched:
        for row in (
            matched[matched["protocol_id"] != matched["protocol_id_committed"]]
            .drop_duplicates("model")
            .itertuples()
        ):
            check.problem(
                f"{folder}: {row.model}: protocol "
                f"{row.protocol_id_committed} committed, {row.protocol_id} now"
            )


def check_identity(label: str, stored: dict | None, fresh: dict, check: CheckReport) -> None:
    """A row's recorded identity against the one it has now: other weights (their sha256),
    another protocol (data files, windows), other hyper-parameters are problems; code changed
    since the row was stamped is a note (``zoo leaderboard`` re-stamps such a row once a sample
    agrees)."""
    from zoo.store.identity import identity_differences, only_code_changed

    differences = identity_differences(stored, fresh)
    if only_code_changed(differences):
        if check.current:
            check.tables[check.current].stale.append(label)
        return
    for d in differences:
        what = (
            "weights are not the ones it records"
            if d.startswith("trained")
            else "a file its model reads changed"
            if d.startswith("model.reads.")
            else "recorded identity differs"
        )
        check.problem(f"{check.current}: {label}: {what}: {d}")


# ---- verifying a stale row on a sample (re-stamping) ----------------------------------------


def self_consistent(stored, folder: Path):
    """None where a stored row's ``results.csv`` is what its own ``windows.npz`` gives (the
    evaluator's sums, :func:`zoo.evaluation.evaluator.frame_from_windows`), else the
    disagreement."""
    from zoo.evaluation.evaluator import frame_from_windows
    from zoo.evaluation.results import EvalResult

    frame = frame_from_windows(stored.windows, stored.protocol)
    agreed = agreement(EvalResult(frame, stored.protocol, stored.windows), folder)
    if agreed.same:
        return None
    return replace(agreed, why=f"its results.csv is not what its windows.npz gives: {agreed.why}")


def verification_record(
    before: dict | None,
    after: dict,
    windows: int,
    seed: int | None,
    agreed,
    data_hash: str | None = None,
):
    """How a row's stored numbers were verified under its new identity: why it was stale (a
    code change, or the identity differences), on ``windows`` windows (``seed``: of a sample;
    None: every window), the code identities before and after, the largest difference, and the
    generated data's bytes it was verified on (``data_hash``, where the data are generated)."""
    import datetime

    from zoo.core.io import code_version

    differences = identity_differences(before, after)
    return {
        "after": "code change" if only_code_changed(differences) else "; ".join(differences),
        "windows": windows,
        **({"seed": seed} if seed is not None else {"every_window": True}),
        "largest_difference": f"{agreed.share:.3f} of the tolerance",
        "code_before": (before or {}).get("code"),
        "code_after": after.get("code"),
        **({"data_hash": data_hash} if data_hash is not None else {}),
        "zoo": code_version(),
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }
