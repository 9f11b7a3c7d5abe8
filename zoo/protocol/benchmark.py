"""Benchmarks: a protocol described as data in ``benchmarks/<name>.yaml``, or in a YAML file of
one's own anywhere.

A benchmark names its data's loader (``loader: package.module:function`` or
``loader: path/to/file.py:function``, a path relative to the YAML file, as a registry entry names
its class), the dataset's name in records, its split, the observed and predicted frame counts,
the default and offered window samplers, the actions and the horizons its tables show. What a
loader returns and must refuse: docs/adding-a-benchmark.md.

Mesh benchmarks (``representation: mesh``) also name the number ``spectral_k`` of Laplacian
eigenvectors of the dataset's spectral basis (what models with ``context: [basis]`` receive) and
the ground truth they score against: ``raw`` vertices or ``spectral`` (the k-coefficient
reconstruction, as SpecTrHuMS does).
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from zoo.core.definitions import DefinitionError, load_definition
from zoo.core.errors import ZooError
from zoo.data.mesh import MeshDataset
from zoo.data.motion import MotionDataset
from zoo.data.skeleton import Skeleton
from zoo.data.windows import check_sampler
from zoo.paths import REPO_ROOT
from zoo.protocol.views import View

BENCHMARK_DIR = REPO_ROOT / "benchmarks"
_REQUIRED = ("name", "dataset", "loader", "split", "input_frames", "output_frames", "sampler")
_OPTIONAL = (
    "loader_options",
    "skeleton",
    "train_split",
    "data_root",
    "samplers",
    "actions",
    "horizons_ms",
    "averaging",
    "description",
    "representation",
    "spectral_k",
    "ground_truth",
    "ground_truths",
    "melv_frames",
    "weights_from",
    "val_split",
)
# What a loader returns for each representation.
DATASET_TYPES = {"joints": MotionDataset, "mesh": MeshDataset}
GROUND_TRUTHS = ("raw", "spectral")


class BenchmarkError(ZooError, ValueError):
    pass


@dataclass(frozen=True)
class Benchmark:
    name: str
    dataset: str  # the dataset's name in records; its data comes from ``loader``
    loader: str
    split: str
    input_frames: int
    output_frames: int
    sampler: str
    source: Path
    loader_options: dict[str, Any] = field(default_factory=dict)
    skeleton_def: str | None = None  # field ``skeleton``: ``module:NAME`` or ``file.py:NAME``
    train_split: str = "train"
    data_root: str | None = None
    samplers: tuple[str, ...] = ()
    actions: tuple[str, ...] = ()
    horizons_ms: tuple[int, ...] = (80, 160, 320, 400, 560, 720, 880, 1000)
    averaging: tuple[str, ...] = ("frame", "cumulative")
    extra: dict[str, Any] = field(default_factory=dict)
    representation: str = "joints"
    spectral_k: int | None = None
    ground_truth: str = "raw"
    ground_truths: tuple[str, ...] = ()
    melv_frames: str | None = None  # None: spectral where there is a basis, else raw
    # A benchmark whose trained models are also scored here (same data, basis and predicted
    # frames; a history at least as long, of which they read the last frames they take).
    weights_from: str | None = None
    # The validation rule of every model trained here (zoo.train.held_out_frames) unless its
    # recipe or the run names another: one rule per benchmark, so its models compare.
    val_split: str | None = None

    @property
    def melv_on(self) -> str:
        """Frames MELV measures edges on: ``spectral`` (reference and scored frames
        reconstructed from the k coefficients, as SpecTrHuMS measures) or ``raw``."""
        return self.melv_frames or ("spectral" if self.spectral_k else "raw")

    @property
    def skeleton(self) -> Skeleton:
        """The skeleton field ``skeleton`` names, which the loader's recordings are on: what a
        model's shape and a checkpoint's protocol need, known without the data."""
        if self.representation == "mesh":
            raise BenchmarkError(f"benchmark {self.name!r} is a mesh benchmark: it has no skeleton")
        try:
            skeleton = load_definition(self.skeleton_def, self.source.parent, "skeleton")
        except DefinitionError as e:
            raise BenchmarkError(f"{self.source}: field 'skeleton': {e}") from e
        if not isinstance(skeleton, Skeleton):
            raise BenchmarkError(
                f"{self.source}: field 'skeleton': {self.skeleton_def} is a "
                f"{type(skeleton).__name__}, expected a zoo.data.skeleton.Skeleton"
            )
        return skeleton

    def resolve_data_root(self, data_root: str | Path | None = None) -> Path | None:
        """``data_root`` if given, else the benchmark's (a relative one is relative to its
        YAML file's folder)."""
        if data_root is not None:
            return Path(data_root)
        if self.data_root is None:
            return None
        path = Path(self.data_root)
        return path if path.is_absolute() else (self.source.parent / path).resolve()

    def loader_function(self):
        """The function named by field ``loader``."""
        try:
            return load_definition(self.loader, self.source.parent, "function")
        except DefinitionError as e:
            raise BenchmarkError(f"{self.source}: field 'loader': {e}") from e

    def load(self, data_root: str | Path | None = None, split: str | None = None):
        """The split's dataset (default: the test split) from the benchmark's loader: a
        :class:`MotionDataset` (joints) or a :class:`zoo.data.mesh.MeshDataset` (mesh),
        generated and cached if need be."""
        loader = self.loader_function()
        kwargs = dict(self.loader_options)
        if self.actions:
            kwargs["actions"] = self.actions
        root = self.resolve_data_root(data_root)
        try:
            inspect.signature(loader).bind(root, split or self.split, **kwargs)
        except TypeError as e:
            raise BenchmarkError(
                f"{self.source}: field 'loader': {self.loader} cannot be called as "
                f"loader(data_root, split{''.join(f', {k}=...' for k in kwargs)}) ({e}); "
                f"see docs/adding-a-benchmark.md"
            ) from None
        except ValueError:  # no signature to read (a builtin): the call itself says
            pass
        try:
            dataset = loader(root, split or self.split, **kwargs)
        except ZooError:
            raise
        except ValueError as e:  # a loader's refusal (a split it has not): one line
            raise BenchmarkError(
                f"{self.source}: {self.loader} refused split {split or self.split!r} of {root}: {e}"
            ) from e
        expected = DATASET_TYPES[self.representation]
        if not isinstance(dataset, expected):
            raise BenchmarkError(
                f"{self.source}: field 'loader': {self.loader} returned "
                f"{type(dataset).__name__}, expected a {expected.__name__} for "
                f"representation {self.representation} (docs/adding-a-benchmark.md)"
            )
        joints = isinstance(dataset, MotionDataset)
        if joints and not _same_skeleton(dataset.skeleton, self.skeleton):
            raise BenchmarkError(
                f"{self.source}: field 'skeleton': {self.loader} gave recordings on skeleton "
                f"{dataset.skeleton.name!r} ({dataset.skeleton.num_joints} joints), the file "
                f"names {self.skeleton_def} ({self.skeleton.name!r}, "
                f"{self.skeleton.num_joints} joints)"
            )
        return dataset

    def view_for(self, representations) -> View:
        """How a model whose registry ``representation`` lists ``representations`` sees this
        benchmark (:class:`zoo.protocol.views.View`): its vertices, or its joints (for a
        skeleton-only model on a mesh benchmark, those its regressor takes from the vertices,
        which the mesh models' MPJPE is scored on)."""
        if self.representation != "mesh":
            return View.JOINTS
        return View.MESH if "mesh" in representations else View.JOINTS

    def model_inputs(
        self,
        context: tuple[str, ...] = (),
        data_root: str | Path | None = None,
        dataset=None,
        view: View = View.MESH,
    ) -> dict[str, Any]:
        """Constructor keywords a model gets from this benchmark (see zoo.models). Mesh
        benchmarks read them from ``dataset`` if given (any split: they share the topology),
        else load the test split; ``view='joints'`` gives a skeleton model's keywords for the
        dataset's regressed joints."""
        if self.representation == "mesh":
            if view == View.JOINTS:
                return self._joints_view_inputs(context, data_root, dataset)
            return self._mesh_model_inputs(context, data_root, dataset)
        inputs = {
            "input_frames": self.input_frames,
            "output_frames": self.output_frames,
            "num_points": len(self.skeleton.used),
        }
        for name in context:
            if name == "parts":
                inputs["parts"] = {k: list(v) for k, v in self.skeleton.parts.items()}
            else:
                raise BenchmarkError(
                    f"benchmark {self.name!r} cannot supply context {name!r}; it supplies: parts"
                )
        return inputs

    # ---- mesh benchmarks ------------------------------------------------------------------------

    def spectral_basis(self, dataset=None, data_root: str | Path | None = None):
        """The :class:`zoo.data.spectral.SpectralBasis` of the dataset's topology with
        ``spectral_k`` vectors, from the basis cache (computed once, then never recomputed)."""
        from zoo.data.spectral import SpectralBasis

        if self.spectral_k is None:
            raise BenchmarkError(
                f"benchmark {self.name!r} ({self.source}) sets no spectral_k: "
                f"it has no spectral basis"
            )
        dataset = dataset if dataset is not None else self.load(data_root)
        return SpectralBasis.load_or_compute(dataset.topology, self.spectral_k)

    def _joints_view_inputs(
        self, context: tuple[str, ...], data_root: str | Path | None, dataset=None
    ) -> dict[str, Any]:
        from zoo.data.mesh import JointsView

        dataset = dataset if dataset is not None else self.load(data_root)
        view = dataset if isinstance(dataset, JointsView) else dataset.joints_view()
        inputs = {
            "input_frames": self.input_frames,
            "output_frames": self.output_frames,
            "num_points": view.num_joints,
        }
        for name in context:
            if name == "parts":
                inputs["parts"] = view.parts
            else:
                raise BenchmarkError(
                    f"benchmark {self.name!r} cannot supply context {name!r} to "
                    f"a model of its regressed joints; it supplies: parts"
                )
        return inputs

    def _mesh_model_inputs(
        self, context: tuple[str, ...], data_root: str | Path | None, dataset=None
    ) -> dict[str, Any]:
        dataset = dataset if dataset is not None else self.load(data_root)
        inputs = {
            "input_frames": self.input_frames,
            "output_frames": self.output_frames,
            "num_points": dataset.topology.num_vertices,
        }
        for name in context:
            if name == "basis":
                inputs["basis"] = self.spectral_basis(dataset)
            else:
                raise BenchmarkError(
                    f"benchmark {self.name!r} cannot supply context {name!r}; it supplies: basis"
                )
        return inputs


def list_benchmarks() -> list[str]:
    return sorted(p.stem for p in BENCHMARK_DIR.glob("*.yaml"))


def get_benchmark(name_or_path: str | Path) -> Benchmark:
    """A benchmark by name (``benchmarks/<name>.yaml``) or by the path of a YAML file."""
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        path = BENCHMARK_DIR / f"{name_or_path}.yaml"
        if not path.is_file():
            raise BenchmarkError(
                f"unknown benchmark {str(name_or_path)!r}; available: "
                f"{', '.join(list_benchmarks()) or '(none)'} "
                f"(or pass the path of a benchmark YAML file)"
            )
    if not path.is_file():
        raise BenchmarkError(f"benchmark file {path} does not exist")
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise BenchmarkError(f"{path}: not valid YAML ({e})") from e
    if not isinstance(raw, dict):
        raise BenchmarkError(f"{path}: expected a mapping of protocol fields")
    missing = [k for k in _REQUIRED if k not in raw]
    if missing:
        raise BenchmarkError(f"{path}: missing field(s) {', '.join(missing)}")
    unknown = sorted(set(raw) - set(_REQUIRED) - set(_OPTIONAL))
    if unknown:
        raise BenchmarkError(
            f"{path}: unknown field(s) {', '.join(unknown)}; valid: "
            f"{', '.join(_REQUIRED + _OPTIONAL)}"
        )
    mesh = _check_mesh_fields(path, raw)
    for key in ("dataset", "loader"):
        if not isinstance(raw[key], str) or not raw[key]:
            raise BenchmarkError(f"{path}: field {key!r} must be a name, got {raw[key]!r}")
    if ":" not in raw["loader"]:
        raise BenchmarkError(
            f"{path}: field 'loader': expected package.module:function or file.py:function "
            f"(a path relative to this file), got {raw['loader']!r}"
        )
    if mesh and "skeleton" in raw:
        raise BenchmarkError(
            f"{path}: field 'skeleton' belongs to joints benchmarks: a mesh benchmark's points "
            f"are its loader's vertices"
        )
    if not mesh and not (isinstance(raw.get("skeleton"), str) and ":" in raw["skeleton"]):
        raise BenchmarkError(
            f"{path}: field 'skeleton': a joints benchmark names the skeleton its recordings "
            f"are on, as package.module:NAME or file.py:NAME (e.g. zoo.data.skeleton:CMU), "
            f"got {raw.get('skeleton')!r}"
        )
    if not isinstance(raw.get("loader_options", {}), dict):
        raise BenchmarkError(
            f"{path}: field 'loader_options' must map the loader's keywords to values"
        )
    for key in ("input_frames", "output_frames"):
        if not isinstance(raw[key], int) or raw[key] < 1:
            raise BenchmarkError(f"{path}: field {key!r} must be a positive integer")
    if not isinstance(raw.get("val_split", ""), str):
        raise BenchmarkError(f"{path}: field 'val_split' must name a validation rule")
    samplers = tuple(raw.get("samplers") or (raw["sampler"],))
    for s in (raw["sampler"], *samplers):
        try:
            check_sampler(s)
        except ValueError as e:
            raise BenchmarkError(f"{path}: {e}") from None
    kwargs = {
        k: tuple(v) if isinstance(v, list) else v
        for k, v in raw.items()
        if k in _OPTIONAL and k not in ("description", "samplers", "skeleton")
    }
    kwargs["skeleton_def"] = raw.get("skeleton")
    if mesh:
        kwargs["representation"] = "mesh"
    bench = Benchmark(
        source=path,
        samplers=samplers,
        extra={"description": raw.get("description")},
        **{k: raw[k] for k in _REQUIRED},
        **kwargs,
    )
    if bench.weights_from is not None:
        _check_weights_from(path, bench)
    return bench


def _same_skeleton(a: Skeleton, b: Skeleton) -> bool:
    """The same joints, tree and scoring rule (offsets aside: positions come with the data)."""
    rule = ("name", "parents", "ignored", "copy_to", "copy_from")
    return all(getattr(a, f) == getattr(b, f) for f in rule)


def _check_weights_from(path: Path, bench: Benchmark) -> None:
    """``weights_from: OTHER``: OTHER's trained models are scored here, so what they were built
    for must be this benchmark's too (the basis itself is compared by hash when they load)."""
    if not isinstance(bench.weights_from, str) or bench.weights_from == bench.name:
        raise BenchmarkError(
            f"{path}: field 'weights_from' must name another benchmark, got {bench.weights_from!r}"
        )
    try:
        other = get_benchmark(bench.weights_from)
    except BenchmarkError as e:
        raise BenchmarkError(f"{path}: field 'weights_from': {e}") from None
    fields = ("representation", "output_frames", "spectral_k")
    differ = [
        f"{f} {getattr(bench, f)!r} here, {getattr(other, f)!r} there"
        for f in fields
        if getattr(bench, f) != getattr(other, f)
    ]
    # its models read the last of the frames observed here: a longer history, never a shorter
    if bench.input_frames < other.input_frames:
        differ.append(
            f"input_frames {bench.input_frames} here, {other.input_frames} there (its models "
            f"read the last {other.input_frames} frames of the history given here)"
        )
    if differ:
        raise BenchmarkError(
            f"{path}: field 'weights_from: {other.name}': its models cannot be "
            f"scored here ({'; '.join(differ)})"
        )


def _check_mesh_fields(path: Path, raw: dict[str, Any]) -> bool:
    """Validate the mesh fields of a benchmark file; True if it is a mesh benchmark."""
    representation = raw.get("representation", "joints")
    if representation not in DATASET_TYPES:
        raise BenchmarkError(
            f"{path}: field 'representation' must be joints or mesh, got {representation!r}"
        )
    if representation != "mesh":
        extra = [
            k for k in ("spectral_k", "ground_truth", "ground_truths", "melv_frames") if k in raw
        ]
        if extra:
            raise BenchmarkError(
                f"{path}: field(s) {', '.join(extra)} belong to mesh benchmarks "
                f"(representation: mesh)"
            )
        return False
    k = raw.get("spectral_k")
    if k is not None and (isinstance(k, bool) or not isinstance(k, int) or k < 1):
        raise BenchmarkError(f"{path}: field 'spectral_k' must be a positive integer, got {k!r}")
    offered = raw.get("ground_truths") or [raw.get("ground_truth", "raw")]
    if raw.get("ground_truth", "raw") not in offered:
        raise BenchmarkError(
            f"{path}: field 'ground_truth' ({raw.get('ground_truth', 'raw')!r}) "
            f"must be one of field 'ground_truths' {offered}"
        )
    for gt in (raw.get("ground_truth", "raw"), *offered):
        if gt not in GROUND_TRUTHS:
            raise BenchmarkError(
                f"{path}: ground truth {gt!r} is not one of {', '.join(GROUND_TRUTHS)}"
            )
        if gt == "spectral" and k is None:
            raise BenchmarkError(f"{path}: ground truth 'spectral' needs field 'spectral_k'")
    melv_frames = raw.get("melv_frames")
    if melv_frames is not None and melv_frames not in GROUND_TRUTHS:
        raise BenchmarkError(
            f"{path}: field 'melv_frames' must be one of "
            f"{', '.join(GROUND_TRUTHS)}, got {melv_frames!r}"
        )
    if melv_frames == "spectral" and k is None:
        raise BenchmarkError(f"{path}: field 'melv_frames: spectral' needs field 'spectral_k'")
    return True
