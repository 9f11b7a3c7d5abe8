"""A few test windows of a mesh benchmark as a browser plays them (``clips.npz`` beside the
benchmark's tables): the observed frames, the ground-truth future and each shipped model's
prediction, on the mesh or, where it has more vertices than a viewer needs to judge a motion,
on a vertex-clustered copy of it. Written by ``zoo site --clips`` (it needs the data and the
weights), read by ``zoo site`` (it needs neither)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from zoo.core.errors import ZooError
from zoo.core.io import atomic_path

CLIPS_FILE = "clips.npz"
CLIP_VERTICES = 1500  # a full-resolution body (13,718 vertices) is clustered down to about this
CLIP_WINDOWS = 2
# Stored positions: int16 steps of this many mm around each window's centre (+-32 m).
STEP_MM = 1.0


class ClipsError(ZooError, ValueError):
    pass


@dataclass
class Clips:
    """``truth`` (W, T_in + T_out, V, 3) and ``predictions[label]`` (W, T_out, V, 3) in mm,
    on ``faces``; ``vertices`` indexes the benchmark's mesh (the clustered copy's vertices)."""

    benchmark: str
    fps: float
    input_frames: int
    windows: np.ndarray
    sequences: list[str]
    faces: np.ndarray
    vertices: np.ndarray
    truth: np.ndarray
    predictions: dict[str, np.ndarray]
    mesh_vertices: int = 0  # the benchmark mesh's (0: as many as kept)
    actions: list[str] = field(default_factory=list)  # each window's action (older files: none)

    @property
    def centre(self) -> np.ndarray:
        """(W, 1, 1, 3): each window's last observed frame's mean vertex, the origin of its
        stored steps."""
        return self.truth[:, self.input_frames - 1].mean(axis=1)[:, None, None]

    def steps(self, positions: np.ndarray) -> np.ndarray:
        """``positions`` (W, T, V, 3) of these windows as int16 steps around each centre."""
        steps = np.round((positions - self.centre) / STEP_MM)
        if np.abs(steps).max(initial=0) > np.iinfo(np.int16).max:
            raise ClipsError(
                f"a clip spans more than {32767 * STEP_MM / 1000:.0f} m from its centre"
            )
        return steps.astype(np.int16)

    def write(self, path: str | Path) -> Path:
        centre = self.centre
        arrays = {
            "benchmark": np.asarray(self.benchmark),
            "fps": np.asarray(self.fps),
            "input_frames": np.asarray(self.input_frames),
            "windows": self.windows.astype(np.int32),
            "sequences": np.asarray(self.sequences, dtype=str),
            "faces": self.faces.astype(np.int32),
            "vertices": self.vertices.astype(np.int32),
            "mesh_vertices": np.asarray(self.mesh_vertices or len(self.vertices)),
            "centre": centre[:, 0, 0],
            "truth": _changes(self.steps(self.truth)),
            **({"actions": np.asarray(self.actions, dtype=str)} if self.actions else {}),
        }
        for label, pred in self.predictions.items():
            arrays[f"pred/{label}"] = _changes(self.steps(pred))
        path = Path(path)
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)
        return path

    @classmethod
    def read(cls, path: str | Path) -> Clips:
        import zipfile
        import zlib

        try:
            with np.load(path, allow_pickle=False) as data:
                centre = data["centre"][:, None, None]

                def mm(key: str) -> np.ndarray:
                    return np.cumsum(data[key], axis=1, dtype=np.int32) * STEP_MM + centre

                clips = cls(
                    benchmark=str(data["benchmark"]),
                    fps=float(data["fps"]),
                    input_frames=int(data["input_frames"]),
                    windows=data["windows"].astype(np.int64),
                    sequences=[str(s) for s in data["sequences"]],
                    faces=data["faces"].astype(np.int64),
                    vertices=data["vertices"].astype(np.int64),
                    mesh_vertices=int(data["mesh_vertices"]),
                    actions=[str(a) for a in data["actions"]] if "actions" in data.files else [],
                    truth=mm("truth"),
                    predictions={
                        k.split("/", 1)[1]: mm(k) for k in data.files if k.startswith("pred/")
                    },
                )
        except (OSError, ValueError, KeyError, IndexError, zipfile.BadZipFile, zlib.error) as exc:
            raise ClipsError(
                f"{path}: not a readable clips file ({exc}); zoo site --clips rewrites it"
            ) from exc
        fault = clips.fault()
        if fault:
            raise ClipsError(f"{path}: {fault}; zoo site --clips rewrites it")
        return clips

    def fault(self) -> str | None:
        """What makes these clips unplayable, in words (None where nothing does)."""
        w, t, v = self.truth.shape[:3] if self.truth.ndim == 4 else (0, 0, 0)
        if self.truth.ndim != 4 or self.truth.shape[3] != 3 or not 0 < self.input_frames < t:
            return f"ground truth of shape {self.truth.shape} with {self.input_frames} observed"
        if (
            len(self.windows) != w
            or len(self.sequences) != w
            or len(self.actions) not in (0, w)
            or len(self.vertices) != v
        ):
            return "windows, sequences, actions or kept vertices do not match the ground truth"
        if self.faces.ndim != 2 or self.faces.shape[1] != 3 or self.faces.size == 0:
            return f"faces of shape {self.faces.shape}, not (F, 3)"
        if self.faces.min() < 0 or self.faces.max() >= v:
            return f"faces index vertices outside 0..{v - 1}"
        expected = (w, t - self.input_frames, v, 3)
        for label, pred in self.predictions.items():
            if pred.shape != expected:
                return f"prediction {label!r} of shape {pred.shape}, not {expected}"
        return None


def _changes(steps: np.ndarray) -> np.ndarray:
    """Frame-to-frame changes along time (axis 1): a motion's small changes compress to half
    of what its positions do."""
    return np.diff(steps, axis=1, prepend=np.zeros_like(steps[:, :1])).astype(np.int16)


def cluster_vertices(
    rest: np.ndarray, faces: np.ndarray, target: int = CLIP_VERTICES
) -> tuple[np.ndarray, np.ndarray]:
    """Vertex clustering on a grid over ``rest`` (V, 3): about ``target`` clusters, each kept
    as its vertex nearest the cluster's mean, and the faces whose corners fall in three
    different clusters. Returns the kept vertices (indices into ``rest``) and the faces on
    them; a mesh of at most ``target`` vertices comes back whole."""
    if len(rest) <= target:
        return np.arange(len(rest)), faces
    low, high = 0.0, float(np.ptp(rest, axis=0).max())
    origin = rest.min(axis=0)
    for _ in range(40):  # the cell size whose grid has about ``target`` occupied cells
        cell = (low + high) / 2
        count = len(np.unique(np.floor((rest - origin) / cell), axis=0))
        low, high = (cell, high) if count > target else (low, cell)
    _, cluster = np.unique(np.floor((rest - origin) / high), axis=0, return_inverse=True)
    cluster = cluster.reshape(-1)
    clusters = cluster.max() + 1
    sums = np.zeros((clusters, 3))
    np.add.at(sums, cluster, rest)
    means = sums / np.bincount(cluster, minlength=clusters)[:, None]
    distance = np.linalg.norm(rest - means[cluster], axis=1)
    order = np.lexsort((distance, cluster))  # by cluster, nearest first
    first = np.r_[True, cluster[order][1:] != cluster[order][:-1]]
    kept = order[first]  # kept[c]: the vertex standing for cluster c
    mapped = cluster[faces]
    mapped = mapped[
        (mapped[:, 0] != mapped[:, 1])
        & (mapped[:, 1] != mapped[:, 2])
        & (mapped[:, 0] != mapped[:, 2])
    ]
    _, unique = np.unique(np.sort(mapped, axis=1), axis=0, return_index=True)
    return kept, mapped[np.sort(unique)]


def spread_windows(bench, dataset, how_many: int = CLIP_WINDOWS) -> list[int]:
    """``how_many`` window numbers of the benchmark's sampler spread evenly over its windows,
    neither end."""
    from zoo.data.windows import window_sampler

    count = len(
        window_sampler(
            bench.sampler,
            [len(s) for s in dataset.sequences],
            bench.input_frames,
            bench.output_frames,
        )
    )
    return sorted({int(w) for w in np.linspace(0, count - 1, how_many + 2)[1:-1]})


def make_clips(bench, dataset, models: dict[str, object], windows: Sequence[int]) -> Clips:
    """The clips of ``windows`` (numbers of the benchmark's sampler) for ``models`` (label ->
    model in eval mode)."""
    from zoo.report.render import predicted_windows

    truth, predictions, rows = None, {}, None
    for label, model in models.items():
        truth, predictions[label], rows = predicted_windows(model, bench, dataset, windows)
    if truth is None:
        raise ClipsError(f"{bench.name}: no shipped mesh model to show")
    kept, faces = cluster_vertices(truth[0, 0], dataset.topology.faces)
    return Clips(
        benchmark=bench.name,
        fps=float(dataset.fps),
        input_frames=bench.input_frames,
        windows=np.asarray(windows),
        sequences=[dataset.sequences[int(r[0])].name for r in rows],
        actions=[str(dataset.sequences[int(r[0])].action) for r in rows],
        faces=faces,
        vertices=kept,
        truth=truth[:, :, kept].astype(np.float64),
        predictions={k: v[:, :, kept].astype(np.float64) for k, v in predictions.items()},
        mesh_vertices=truth.shape[2],
    )


def write_benchmark_clips(
    benchmark: str, registry, weights_root: Path, path: Path, data_root=None
) -> Path:
    """Load ``benchmark``'s test data and every shipped weights file of it (best validation,
    not ``@last``), and write their :func:`make_clips` to ``path``."""
    from zoo.hub.model_source import ModelSource
    from zoo.hub.weights import available_weights, weights_file
    from zoo.protocol.benchmark import get_benchmark

    bench = get_benchmark(benchmark)
    if not bench.strategy.drawn:
        raise ClipsError(
            f"benchmark {benchmark!r} is a {bench.representation} one; clips are meshes"
        )
    labels = sorted(
        label for b, label in available_weights(weights_root) if b == benchmark and "@" not in label
    )
    if not labels:
        raise ClipsError(f"{weights_root}/{benchmark}: no shipped weights to show")
    dataset = bench.load(data_root)
    models = {}
    for label in labels:
        source = ModelSource.of(weights=weights_file(benchmark, label, weights_root))
        models[label] = source.load(registry, bench, dataset, data_root).model.eval()
    return make_clips(bench, dataset, models, spread_windows(bench, dataset)).write(path)
