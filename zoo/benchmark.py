"""Benchmarks: a protocol described as data in ``benchmarks/<name>.yaml``.

A benchmark names its dataset and split, the observed and predicted frame counts, the default
and offered window samplers, the actions and the horizons its tables show.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from zoo.data.motion import DATASETS, MotionDataset
from zoo.data.skeleton import CMU, H36M, Skeleton
from zoo.data.windows import check_sampler
from zoo.errors import ZooError
from zoo.registry import REPO_ROOT

BENCHMARK_DIR = REPO_ROOT / "benchmarks"
SKELETON_OF = {"cmu_mocap": CMU, "h36m": H36M}
_REQUIRED = ("name", "dataset", "split", "input_frames", "output_frames", "sampler")
_OPTIONAL = ("train_split", "data_root", "samplers", "actions", "horizons_ms", "averaging",
             "description")


class BenchmarkError(ZooError, ValueError):
    pass


@dataclass(frozen=True)
class Benchmark:
    name: str
    dataset: str
    split: str
    input_frames: int
    output_frames: int
    sampler: str
    source: Path
    train_split: str = "train"
    data_root: str | None = None
    samplers: tuple[str, ...] = ()
    actions: tuple[str, ...] = ()
    horizons_ms: tuple[int, ...] = (80, 160, 320, 400, 560, 720, 880, 1000)
    averaging: tuple[str, ...] = ("frame", "cumulative")
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def representation(self) -> str:
        return "joints"

    @property
    def skeleton(self) -> Skeleton:
        return SKELETON_OF[self.dataset]

    def resolve_data_root(self, data_root: str | Path | None = None) -> Path | None:
        if data_root is not None:
            return Path(data_root)
        if self.data_root is None:
            return None
        path = Path(self.data_root)
        return path if path.is_absolute() else (REPO_ROOT / path).resolve()

    def load(self, data_root: str | Path | None = None, split: str | None = None) -> MotionDataset:
        loader = DATASETS[self.dataset]
        kwargs = {"actions": self.actions} if self.actions else {}
        return loader(self.resolve_data_root(data_root), split or self.split, **kwargs)

    def model_inputs(self, context: tuple[str, ...] = ()) -> dict[str, Any]:
        """Constructor keywords a model gets from this benchmark (see zoo.models)."""
        inputs = {"input_frames": self.input_frames, "output_frames": self.output_frames,
                  "num_points": len(self.skeleton.used)}
        for name in context:
            if name == "parts":
                inputs["parts"] = {k: list(v) for k, v in self.skeleton.parts.items()}
            else:
                raise BenchmarkError(f"benchmark {self.name!r} cannot supply context {name!r}; "
                                     f"it supplies: parts")
        return inputs


def list_benchmarks() -> list[str]:
    return sorted(p.stem for p in BENCHMARK_DIR.glob("*.yaml"))


def get_benchmark(name_or_path: str | Path) -> Benchmark:
    """A benchmark by name (``benchmarks/<name>.yaml``) or by the path of a YAML file."""
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        path = BENCHMARK_DIR / f"{name_or_path}.yaml"
        if not path.is_file():
            raise BenchmarkError(f"unknown benchmark {str(name_or_path)!r}; available: "
                                 f"{', '.join(list_benchmarks()) or '(none)'} "
                                 f"(or pass the path of a benchmark YAML file)")
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
        raise BenchmarkError(f"{path}: unknown field(s) {', '.join(unknown)}; valid: "
                             f"{', '.join(_REQUIRED + _OPTIONAL)}")
    if raw["dataset"] not in SKELETON_OF:
        raise BenchmarkError(f"{path}: field 'dataset': unknown dataset {raw['dataset']!r}; "
                             f"known: {', '.join(SKELETON_OF)}")
    for key in ("input_frames", "output_frames"):
        if not isinstance(raw[key], int) or raw[key] < 1:
            raise BenchmarkError(f"{path}: field {key!r} must be a positive integer")
    samplers = tuple(raw.get("samplers") or (raw["sampler"],))
    for s in (raw["sampler"], *samplers):
        try:
            check_sampler(s)
        except ValueError as e:
            raise BenchmarkError(f"{path}: {e}") from None
    kwargs = {k: tuple(v) if isinstance(v, list) else v for k, v in raw.items()
              if k in _OPTIONAL and k not in ("description", "samplers")}
    return Benchmark(source=path, samplers=samplers, extra={"description": raw.get("description")},
                     **{k: raw[k] for k in _REQUIRED}, **kwargs)
