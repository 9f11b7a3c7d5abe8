"""Benchmarks: a protocol described as data in ``benchmarks/<name>.yaml``, or in a YAML file of
one's own anywhere.

A benchmark names its data's loader (``loader: package.module:function`` or
``loader: path/to/file.py:function``, a path relative to the YAML file, as a registry entry names
its class), the dataset's name in records, its split, the observed and predicted frame counts,
the default and offered window samplers, the actions and the horizons its tables show. What a
loader returns and must refuse: docs/adding-a-benchmark.md.

Its ``representation`` (:data:`REPRESENTATIONS`: ``joints``, :mod:`zoo.protocol.joints`;
``mesh``, :mod:`zoo.protocol.mesh`) is the one object that knows what its points are: a joints
benchmark names its ``skeleton``, a mesh benchmark its ``spectral_k`` and ground truth.
"""

from __future__ import annotations

import dataclasses
import inspect
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import pydantic
import yaml
from pydantic import AfterValidator, ConfigDict, Field, StrictInt, StringConstraints

from zoo.core.definitions import DefinitionError, load_definition
from zoo.core.errors import BenchmarkError, ZooError
from zoo.core.io import load_yaml, yaml_problem
from zoo.core.schema import line_of, validated
from zoo.data.skeleton import Skeleton
from zoo.data.windows import check_sampler
from zoo.paths import REPO_ROOT
from zoo.protocol.joints import JointsRepresentation
from zoo.protocol.mesh import GroundTruth, MeshRepresentation
from zoo.protocol.representation import Representation
from zoo.protocol.views import View

BENCHMARK_DIR = REPO_ROOT / "benchmarks"
# Each kind of points a benchmark can have, by the word its file writes.
REPRESENTATIONS: dict[str, Representation] = {
    r.name: r for r in (JointsRepresentation(), MeshRepresentation())
}
# the words a model's registry entry may write: each representation's, and the other kinds of
# models each feeds (a joints benchmark's exp-map angles)
MODEL_REPRESENTATIONS: tuple[str, ...] = tuple(
    dict.fromkeys(w for r in REPRESENTATIONS.values() for w in (r.name, *r.model_kinds))
)


def _named(spec: str) -> str:
    if ":" not in spec:
        raise ValueError(
            f"expected package.module:NAME or file.py:NAME (a path relative to this file), "
            f"got {spec!r}"
        )
    return spec


Name = Annotated[str, StringConstraints(min_length=1)]
Definition = Annotated[str, AfterValidator(_named)]
Sampler = Annotated[str, AfterValidator(check_sampler)]  # its SamplerError is a ValueError
Frames = Annotated[StrictInt, Field(ge=1)]
# The validation rules (zoo.train.split says what each holds out): a benchmark's default and a
# recipe's own name one of them.
ValSplit = Literal["auto", "tails", "actions", "recordings"]
HORIZONS_MS = (80, 160, 320, 400, 560, 720, 880, 1000)
# Fields one representation alone writes, by their names in the schema (the file's ``skeleton``
# is the schema's ``skeleton_def``: ``Benchmark.skeleton`` is the skeleton it names).
_OWN_FIELDS = {
    ("skeleton_def" if name == "skeleton" else name): r
    for r in REPRESENTATIONS.values()
    for name in r.fields
}


@pydantic.dataclasses.dataclass(frozen=True, config=ConfigDict(extra="forbid"))
class BenchmarkFields:
    """A benchmark as its YAML file writes it: the schema the file is read through
    (zoo.core.schema), each field once."""

    name: Name
    dataset: Name  # the dataset's name in records; its data comes from ``loader``
    loader: Definition
    split: Name
    input_frames: Frames
    output_frames: Frames
    sampler: Sampler
    loader_options: dict[str, Any] = field(default_factory=dict)
    train_split: Name = "train"
    data_root: str | None = None
    # the samplers offered; none written: the default one alone
    samplers: tuple[Sampler, ...] = Field((), validate_default=True)
    actions: tuple[str, ...] = ()
    horizons_ms: tuple[Annotated[StrictInt, Field(ge=1)], ...] = HORIZONS_MS
    averaging: tuple[Literal["frame", "cumulative"], ...] = ("frame", "cumulative")
    description: str = ""
    representation: Literal[tuple(REPRESENTATIONS)] = "joints"
    # the skeleton the loader's recordings are on (joints only): ``module:NAME``, ``file.py:NAME``;
    # after ``representation``, which its check reads
    skeleton_def: Definition | None = Field(None, alias="skeleton")
    spectral_k: Frames | None = None
    ground_truth: GroundTruth = "raw"
    ground_truths: tuple[GroundTruth, ...] = ()
    melv_frames: GroundTruth | None = None  # None: spectral where there is a basis, else raw
    # A benchmark whose trained models are also scored here (same data, basis and predicted
    # frames; a history at least as long, of which they read the last frames they take).
    weights_from: Name | None = None
    # The validation rule of every model trained here (zoo.train.held_out_frames) unless its
    # recipe or the run names another: one rule per benchmark, so its models compare.
    val_split: ValSplit | None = None

    @pydantic.field_validator("samplers")
    @classmethod
    def _default_alone(cls, samplers: tuple, info: pydantic.ValidationInfo) -> tuple:
        return samplers or ((info.data["sampler"],) if "sampler" in info.data else ())

    @pydantic.field_validator(*_OWN_FIELDS)
    @classmethod
    def _own_field(cls, value: Any, info: pydantic.ValidationInfo) -> Any:
        owner = _OWN_FIELDS[info.field_name]
        if info.data.get("representation", owner.name) != owner.name:
            raise ValueError(f"belongs to {owner} benchmarks (representation: {owner})")
        return value

    @pydantic.model_validator(mode="after")
    def _fields_of_representation(self) -> BenchmarkFields:
        REPRESENTATIONS[self.representation].check_fields(self)
        return self


@dataclass(frozen=True, kw_only=True)
class Benchmark(BenchmarkFields):
    """A benchmark: its file's fields and the file (``source``) they were read from."""

    source: Path

    @property
    def strategy(self) -> Representation:
        """The object of its ``representation``: all that depends on what its points are."""
        return REPRESENTATIONS[self.representation]

    @property
    def melv_on(self) -> str:
        """Frames MELV measures edges on: ``spectral`` (reference and scored frames
        reconstructed from the k coefficients, as SpecTrHuMS measures) or ``raw``."""
        return self.melv_frames or ("spectral" if self.spectral_k else "raw")

    @property
    def skeleton(self) -> Skeleton:
        """The skeleton field ``skeleton`` names, which the loader's recordings are on: what a
        model's shape and a checkpoint's protocol need, known without the data."""
        if self.skeleton_def is None:
            raise BenchmarkError(
                f"benchmark {self.name!r} is a {self.representation} benchmark: it has no skeleton"
            )
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
        except ValueError as e:  # a loader's refusal (a split it has not, a bad file): one line
            raise BenchmarkError(
                f"{self.source}: field 'loader': {self.loader} could not load split "
                f"{split or self.split!r} of {root}: {e}"
            ) from e
        expected = self.strategy.dataset_type
        if not isinstance(dataset, expected):
            raise BenchmarkError(
                f"{self.source}: field 'loader': {self.loader} returned "
                f"{type(dataset).__name__}, expected a {expected.__name__} for "
                f"representation {self.representation} (docs/adding-a-benchmark.md)"
            )
        if not dataset.sequences:
            raise BenchmarkError(
                f"{self.source}: field 'loader': {self.loader} returned no recordings for split "
                f"{split or self.split!r} of {root}"
            )
        self.strategy.check_dataset(self, dataset)
        return dataset

    @property
    def own_view(self) -> View:
        """How a model of this benchmark's own representation sees it."""
        return self.view_for((self.representation,))

    def view_for(self, representations) -> View:
        """How a model whose registry ``representation`` lists ``representations`` sees this
        benchmark (:class:`zoo.protocol.views.View`): its vertices, or its joints (for a
        skeleton-only model on a mesh benchmark, those its regressor takes from the vertices,
        which the mesh models' MPJPE is scored on)."""
        return self.strategy.view_for(representations)

    def model_inputs(
        self,
        context: tuple[str, ...] = (),
        data_root: str | Path | None = None,
        dataset=None,
        view: View | None = None,
    ) -> dict[str, Any]:
        """Constructor keywords a model gets from this benchmark (see zoo.models), read from
        ``dataset`` where they need the data (else from the test split, loaded);
        ``view``: the benchmark's own (None), or ``joints`` on a mesh benchmark for a skeleton
        model's keywords for the dataset's regressed joints."""
        data = (lambda: dataset) if dataset is not None else (lambda: self.load(data_root))
        return self.strategy.model_inputs(self, tuple(context), view or self.own_view, data)


def representation_of(record: dict[str, Any]) -> Representation:
    """The representation a protocol record was planned under (a joints record does not name
    it: the word came with meshes, and a record is hashed as it was written)."""
    return REPRESENTATIONS[record.get("representation", JointsRepresentation.name)]


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
    path = path.resolve()  # its loader, skeleton and data are found beside it, from any folder
    try:
        raw = load_yaml(path.read_text())
    except yaml.YAMLError as e:
        raise BenchmarkError(f"{path}: not valid YAML: {yaml_problem(e)}") from e
    if not isinstance(raw, dict):
        raise BenchmarkError(f"{path}: expected a mapping of protocol fields")
    fields = validated(BenchmarkFields, raw, path, error=BenchmarkError)
    values = {f.name: getattr(fields, f.name) for f in dataclasses.fields(BenchmarkFields)}
    bench = Benchmark(**values, source=path)
    if bench.weights_from is not None:
        _check_weights_from(path, bench)
    return bench


def _check_weights_from(path: Path, bench: Benchmark) -> None:
    """``weights_from: OTHER``: OTHER's trained models are scored here, so what they were built
    for must be this benchmark's too (the basis itself is compared by hash when they load)."""
    where = f"{path}, line {line_of(path, ('weights_from',))}: field 'weights_from'"
    if bench.weights_from == bench.name:
        raise BenchmarkError(f"{where}: must name another benchmark, not this one")
    other_file = Path(bench.weights_from)
    try:  # a name, or a YAML file's path relative to this one
        other = get_benchmark(
            path.parent / other_file
            if other_file.suffix in (".yaml", ".yml") and not other_file.is_absolute()
            else bench.weights_from
        )
    except BenchmarkError as e:
        raise BenchmarkError(f"{where}: {e}") from None
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
            f"{where}: the models of {other.name} cannot be scored here ({'; '.join(differ)})"
        )
