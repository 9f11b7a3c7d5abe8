"""A result as it is kept: the long-format rows (``results.csv``), the protocol record
(``protocol.json``), the per-window errors (``windows.npz``) and the tables (``tables.md``) of
one model under one protocol, read and written atomically; and a leaderboard's table read as
one result (:func:`read_table`: its rows' folders, listed by the table's ``protocol.json``).
Nothing here computes a number (the evaluator, :mod:`zoo.evaluation.evaluator`, does)."""

# zoo: computes no number

from __future__ import annotations

import json
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from zoo.core.errors import EvaluationError
from zoo.core.io import atomic_path, atomic_write_json, atomic_write_text, replace_folder
from zoo.evaluation.markdown import markdown_tables

RESULT_COLUMNS = [
    "model",
    "benchmark",
    "action",
    "metric",
    "averaging",
    "joints",
    "horizon_ms",
    "frame",
    "value",
    "std",
    "windows",
    "dataset",
    "split",
    "sampler",
    "task",
    "input_frames",
    "output_frames",
    "fps",
    "protocol_id",
]
WINDOWS_FILE = "windows.npz"
# What makes a folder a leaderboard's table (zoo.report.outputs writes it); its rows are the result
# folders beside it that its protocol.json lists. The rows' numbers are kept once, in the rows'
# own results.csv: a table-wide copy doubled every row's bytes and grew past the 5 MiB a
# tracked file may have at about twelve mesh rows.
TABLE_FILE = "leaderboard.md"


@dataclass
class WindowErrors:
    """Every scored window's per-frame error, beside the averages (``windows.npz``): where each
    window comes from (``sequence`` index into ``sequences``, first frame ``start``, ``action``)
    and, per ``(model, metric, joints)``, its errors ``(W, T_out)`` at every predicted frame
    (float32; the averages in ``results.csv`` are summed in float64 from the exact values)."""

    sequences: list[str]
    sequence: np.ndarray
    start: np.ndarray
    action: np.ndarray
    errors: dict[tuple[str, str, str], np.ndarray]
    protocol_id: str
    window_frames: int

    def get(self, model: str, metric: str, joints: str) -> np.ndarray:
        key = (model, metric, joints)
        if key not in self.errors:
            raise EvaluationError(
                f"no per-window errors for model {model!r}, metric "
                f"{metric!r}, joints {joints!r}; stored: "
                f"{', '.join('/'.join(k) for k in self.errors)}"
            )
        return self.errors[key]

    def write(self, path: str | Path) -> None:
        arrays = {
            "sequences": np.asarray(self.sequences, dtype=str),
            "sequence": self.sequence.astype(np.int32),
            "start": self.start.astype(np.int32),
            "action": np.asarray(self.action, dtype=str),
            "protocol_id": np.asarray(self.protocol_id),
            "window_frames": np.asarray(self.window_frames),
        }
        for (model, metric, joints), values in self.errors.items():
            arrays[f"errors/{model}/{metric}/{joints}"] = values.astype(np.float32)
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)

    @classmethod
    def read(cls, path: str | Path) -> WindowErrors:
        try:
            with np.load(path, allow_pickle=False) as data:
                keys = [k for k in data.files if k.startswith("errors/")]
                return cls(
                    sequences=[str(x) for x in data["sequences"]],
                    sequence=data["sequence"].astype(np.int64),
                    start=data["start"].astype(np.int64),
                    action=data["action"].astype(str),
                    errors={tuple(k.split("/", 3)[1:]): data[k] for k in keys},
                    protocol_id=str(data["protocol_id"]),
                    window_frames=int(data["window_frames"]),
                )
        except (OSError, ValueError, KeyError) as exc:
            raise EvaluationError(
                f"{path}: not a readable per-window error file ({exc}); "
                f"re-evaluate to rebuild it (zoo eval / zoo leaderboard)"
            ) from exc


class Summary(pd.DataFrame):
    """A DataFrame that prints whole: every horizon, however wide the terminal."""

    @property
    def _constructor(self):
        return Summary

    def __repr__(self) -> str:
        return self.to_string()

    def __str__(self) -> str:
        return self.to_string()


@dataclass
class EvalResult:
    frame: pd.DataFrame
    protocol: dict[str, Any]
    windows: WindowErrors | None = None

    def write(self, out_dir: str | Path, replace: bool = True) -> Path:
        """``results.csv``, ``protocol.json``, ``tables.md`` and ``windows.npz`` in ``out_dir``.
        The folder is replaced as a whole (filled beside it, then renamed into place) under a
        lock that refuses a second writer; ``replace=False`` writes into a fresh folder that the
        caller replaces as a whole itself."""
        out_dir = Path(out_dir)
        tables = markdown_tables(self.frame, {self.protocol["protocol_id"]: self.protocol})
        with replace_folder(out_dir) if replace else nullcontext(out_dir) as folder:
            atomic_write_text(folder / "results.csv", self.frame.to_csv(index=False))
            atomic_write_json(folder / "protocol.json", self.protocol)
            atomic_write_text(folder / "tables.md", tables)
            if self.windows is not None:
                self.windows.write(folder / WINDOWS_FILE)
        return out_dir

    def summary(self, metric: str | None = None, averaging: str = "frame") -> Summary:
        """The action average per horizon (columns, ms) of every model and joint protocol of
        ``metric`` (default: every metric), under ``averaging``; printed whole."""
        frame = self.frame[
            (self.frame["action"] == "average") & (self.frame["averaging"] == averaging)
        ]
        if metric is not None:
            frame = frame[frame["metric"] == metric]
        return Summary(
            frame.pivot_table(
                index=["model", "metric", "joints"], columns="horizon_ms", values="value"
            )
        )

    @property
    def identity(self) -> dict[str, Any] | None:
        """What was measured (:mod:`zoo.store.identity`), as recorded in ``protocol.json``."""
        return self.protocol.get("provenance", {}).get("identity")

    @classmethod
    def read(cls, out_dir: str | Path) -> EvalResult:
        out_dir = Path(out_dir)
        for name in ("results.csv", "protocol.json"):
            if not (out_dir / name).is_file():
                raise EvaluationError(f"{out_dir / name}: missing (not an evaluation folder)")
        protocol = json.loads((out_dir / "protocol.json").read_text())
        windows = (
            WindowErrors.read(out_dir / WINDOWS_FILE)
            if (out_dir / WINDOWS_FILE).is_file()
            else None
        )
        if windows is not None and windows.protocol_id != protocol["protocol_id"]:
            raise EvaluationError(
                f"{out_dir / WINDOWS_FILE}: measured under protocol "
                f"{windows.protocol_id}, but {out_dir / 'protocol.json'} says "
                f"{protocol['protocol_id']}; re-evaluate the folder"
            )
        return cls(frame=pd.read_csv(out_dir / "results.csv"), protocol=protocol, windows=windows)


def table_files(root: str | Path, depth: int = 1) -> list[Path]:
    """Every ``leaderboard.md`` ``depth`` folders below ``root`` (1: a benchmark's tables, 2:
    every benchmark's), sorted; a table being written (a hidden folder,
    :func:`zoo.core.io.replace_folder`) is none of them."""
    pattern = "/".join(["*"] * depth + [TABLE_FILE])
    return sorted(
        p
        for p in Path(root).glob(pattern)
        if not any(part.startswith(".") for part in p.parts[-1 - depth : -1])
    )


def table_labels(folder: str | Path) -> list[str]:
    """The labels of a leaderboard table's rows (``<folder>/<label>/``), in the table's order,
    as its ``protocol.json`` lists them."""
    return _labels(_table_protocol(folder), Path(folder) / "protocol.json")


def _table_protocol(folder: str | Path) -> dict[str, Any]:
    path = Path(folder) / "protocol.json"
    if not path.is_file():
        raise EvaluationError(f"{path}: missing (not a leaderboard table)")
    return json.loads(path.read_text())


def _labels(protocol: dict[str, Any], path: Path) -> list[str]:
    runs = protocol.get("provenance", {}).get("runs")
    labels = [(run.get("identity") or {}).get("label") for run in runs or ()]
    if not labels or None in labels:
        raise EvaluationError(
            f"{path}: provenance.runs does not name every row's label (identity.label); "
            f"regenerate the table with zoo leaderboard"
        )
    return labels


def read_table(folder: str | Path, columns: list[str] | None = None) -> EvalResult:
    """A leaderboard table as one result: the rows of every result folder it lists, in its
    order, under the table's own ``protocol.json`` (no per-window errors); ``columns``: only
    those of each row's ``results.csv``."""
    folder = Path(folder)
    protocol = _table_protocol(folder)
    frames = []
    for label in _labels(protocol, folder / "protocol.json"):
        path = folder / label / "results.csv"
        if not path.is_file():
            raise EvaluationError(f"{path}: missing (a row that {folder}/protocol.json lists)")
        frames.append(pd.read_csv(path, usecols=columns))
    return EvalResult(frame=pd.concat(frames, ignore_index=True), protocol=protocol)
