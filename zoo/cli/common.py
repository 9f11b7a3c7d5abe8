"""What the commands share: the help formatter, the common options, deprecated spellings,
``--set`` values, the registry, a model source and its benchmark, usage errors."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from zoo.core.errors import ZooError
from zoo.core.io import load_yaml
from zoo.models.registry import load_registry
from zoo.paths import REPO_ROOT


class UsageError(ZooError, ValueError):
    """A command-line argument is wrong; the message names it and what was expected."""


# A library call's argument -> the flag that gives it on the command line, where they differ
# by more than dashes for underscores.
FLAGS = {"out_dir": "--out", "recipe_overrides": "--train-set", "overrides": "--set"}


def in_flags(error: ZooError) -> str:
    """A library error's message, its leading parameter named by the command line's flag."""
    text, parameter = str(error), getattr(error, "parameter", None)
    if parameter and text.startswith(f"{parameter}:"):
        flag = FLAGS.get(parameter, "--" + parameter.replace("_", "-"))
        text = flag + text[len(parameter) :]
    return text


def checked_sampler(name: str, bench=None) -> str:
    """``--sampler``'s value, refused in one line before any data is read; an unknown one lists
    the samplers that apply to ``bench`` (rand256, drawn from Human3.6M's two sub-actions, only
    where the benchmark offers it)."""
    from zoo.data.windows import SamplerError, check_sampler

    general = "allK, strideK, strideK_strict (K a positive integer, e.g. stride5, all50)"
    h36m = bench is None or "rand256" in bench.samplers
    try:
        check_sampler(name)
    except SamplerError:
        tables = f"{', '.join(bench.samplers)} (its tables), " if bench is not None else ""
        extra = "rand256, " if h36m and "rand256" not in tables else ""
        where = f" for benchmark {bench.name}" if bench is not None else ""
        raise UsageError(
            f"--sampler {name!r}: unknown{where}; valid: {tables}{extra}{general}"
        ) from None
    if name == "rand256" and not h36m:
        raise UsageError(
            f"--sampler rand256: defined for Human3.6M's two sub-actions per action, not for "
            f"benchmark {bench.name}; valid: {', '.join(bench.samplers)} (its tables), {general}"
        )
    return name


def registry_hint(error: ZooError, folder: Path | None = None) -> str:
    """For an unknown model: the registry files in ``folder`` (the working one) that define it,
    as the ``--registry`` to add; empty otherwise."""
    from zoo.models.registry import UnknownModelError

    if not isinstance(error, UnknownModelError):
        return ""
    defining = []
    for path in sorted((folder or Path.cwd()).glob("*.y*ml")):
        try:
            models = (load_yaml(path.read_text()) or {}).get("models")
        except (OSError, UnicodeDecodeError, yaml.YAMLError, AttributeError):
            continue
        if isinstance(models, dict) and error.model in models:
            defining.append(path.name)
    if not defining:
        return ""
    return f" ({defining[0]} here defines {error.model!r}: add --registry {defining[0]})"


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Each option's default shown by the formatter (none where it has none), paths inside the
    repository shown relative to it."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if (
            "%(default)" in text
            or default is None
            or default is False
            or default == []
            or default is argparse.SUPPRESS
        ):
            return text
        return text + " (default: %(default)s)"

    def _expand_help(self, action):
        default = action.default
        if isinstance(default, str) and default.startswith(str(REPO_ROOT) + "/"):
            action = argparse.Namespace(
                **{**vars(action), "default": default[len(str(REPO_ROOT)) + 1 :] + "/"}
            )
        return super()._expand_help(action)


def add_command(sub, name: str, help: str, run, **kwargs) -> argparse.ArgumentParser:
    """A subcommand with the shared formatter, running ``run(args)``."""
    p = sub.add_parser(name, help=help, description=help, formatter_class=HelpFormatter, **kwargs)
    p.set_defaults(func=run)
    return p


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:  # argparse keeps its subcommands nowhere public
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def action_first(parser: argparse.ArgumentParser, argv: Sequence[str]) -> list[str]:
    """``argv`` with the options written between a nested command and its action moved after
    the action (``zoo weights --weights-dir X list`` -> ``zoo weights list --weights-dir X``):
    the order the positional actions of earlier releases accepted, which argparse's nested
    subcommands refuse. Help (``zoo weights -h list``) stays the command's."""
    argv = list(argv)
    commands = _subparsers(parser)
    at = next((i for i, token in enumerate(argv) if token in commands), None)
    if at is None:
        return argv
    actions = _subparsers(commands[argv[at]])
    if not actions:
        return argv
    values = {  # option string -> how many values follow it
        option: 1 if a.nargs is None else a.nargs if isinstance(a.nargs, int) else 1
        for child in actions.values()
        for a in child._actions
        for option in a.option_strings
    }
    i = at + 1
    while i < len(argv) and argv[i].startswith("-") and argv[i] != "--":
        option = argv[i]
        if option in ("-h", "--help"):
            return argv
        if "=" not in option:
            # argparse takes a unique prefix of a long option (--data for --data-root)
            known = [o for o in values if o.startswith(option)] if option.startswith("--") else []
            i += values.get(option, values[known[0]] if len(known) == 1 else 0)
        i += 1
    if i == at + 1 or i >= len(argv) or argv[i] not in actions:
        return argv
    return argv[: at + 1] + [argv[i]] + argv[at + 1 : i] + argv[i + 1 :]


class Deprecated(argparse.Action):
    """An old spelling of an option: it still works this release, with a line saying which
    one replaces it."""

    def __init__(self, option_strings, dest, new: str, **kwargs) -> None:
        self.new = new
        super().__init__(option_strings, dest, help=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        print(
            f"{parser.prog}: {option_string} is deprecated, use {self.new} (the old spelling "
            f"goes in the next release)",
            file=sys.stderr,
        )
        setattr(namespace, self.dest, values)


def registry_option(p) -> None:
    p.add_argument(
        "--registry",
        action="append",
        default=[],
        metavar="YAML",
        help="extra registry file (your own baselines); repeatable",
    )


def common_options(p) -> None:
    """``--registry``, ``--data-root`` and ``--device``, which every command that runs a model
    takes."""
    registry_option(p)
    p.add_argument("--data-root", help="dataset folder (default: the benchmark's)")
    p.add_argument("--device", default="cpu", help="torch device")


def model_source_options(p, benchmark_help: str) -> None:
    """Where the model comes from (``--model``, ``--checkpoint`` or ``--weights``) and the
    benchmark, for the commands that run one model."""
    p.add_argument("--model", help="registered model name")
    p.add_argument("--checkpoint", help="trained checkpoint (from zoo train)")
    p.add_argument(
        "--weights", help="shipped weights file (weights/<benchmark>/<label>.safetensors)"
    )
    p.add_argument("--benchmark", help=benchmark_help)


def results_option(p, help: str = "results root") -> None:
    """``--results``: the results root (``--out``, its old spelling, where it meant that)."""
    from zoo.store.layout import RESULTS_DIR

    p.add_argument("--results", default=str(RESULTS_DIR), help=help)


def weights_dir_option(p, help: str = "folder of shipped weights <benchmark>/<label>.safetensors"):
    p.add_argument("--weights-dir", default=str(REPO_ROOT / "weights"), help=help)


def parse_overrides(items: Sequence[str] | None) -> dict[str, Any]:
    """``--set key=value`` pairs, values parsed as YAML scalars (``3``, ``0.5``, ``[1, 2]``)."""
    out = {}
    for item in items or ():
        if "=" not in item:
            raise UsageError(f"--set expects key=value, got {item!r}")
        key, value = item.split("=", 1)
        out[key.strip()] = _numbers_as_numbers(load_yaml(value))
    return out


def _numbers_as_numbers(value: Any) -> Any:
    """YAML 1.1 reads ``1e-3`` (no dot) as a string; a number is meant, in a value or nested."""
    if isinstance(value, str):
        try:
            return (
                float(value)
                if value.strip().lower() not in ("nan", "inf", "-inf", "infinity")
                else value
            )
        except ValueError:
            return value
    if isinstance(value, dict):
        return {k: _numbers_as_numbers(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_numbers_as_numbers(v) for v in value]
    return value


def registry_of(args):
    return load_registry(*(args.registry or ()))


def model_source(args):
    from zoo.hub.model_source import ModelSource

    return ModelSource.of(
        model=args.model,
        checkpoint=getattr(args, "checkpoint", None),
        weights=getattr(args, "weights", None),
        overrides=parse_overrides(args.set),
        label=getattr(args, "label", None),
    )


def benchmark_of(args, source, default: str):
    """The benchmark asked for, else the one a trained model was trained for, else
    ``default``."""
    from zoo.protocol.benchmark import get_benchmark

    return get_benchmark(args.benchmark or source.benchmark() or default)


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def task_options(p) -> None:
    """``--task`` (one of the evaluator's tasks, ``zoo.core.options.TASKS``) and its horizon."""
    from zoo.core.options import TASKS

    p.add_argument(
        "--task",
        default="prediction",
        choices=list(TASKS),
        help="what the model is asked: the next frames, the frames between, or a long rollout",
    )
    p.add_argument("--horizon-frames", type=int, help="frames to predict for --task longterm")


def check_device(device: str) -> None:
    """An unknown device, or one this machine lacks, is a usage error before any work."""
    import torch

    try:
        kind = torch.device(device).type
    except (RuntimeError, ValueError):
        raise UsageError(
            f"--device {device!r}: not a torch device; e.g. cpu, cuda, cuda:1"
        ) from None
    if kind == "cuda" and not torch.cuda.is_available():
        raise UsageError(
            f"--device {device}: this machine has no CUDA device (torch "
            f"{torch.__version__}); use --device cpu"
        )
    if kind not in ("cpu", "cuda"):
        raise UsageError(f"--device {device}: the zoo runs on cpu or cuda, not {kind}")


def shape_overrides(overrides: dict[str, Any], benchmark: str | None) -> None:
    from zoo.models.registry import SHAPE_ARGS

    fixed = sorted(set(overrides) & set(SHAPE_ARGS))
    if fixed:
        raise UsageError(
            f"--set {', '.join(fixed)}: fixed by the benchmark "
            f"({benchmark or 'cmu'}), not a hyper-parameter; use a benchmark YAML "
            f"file with other input_frames / output_frames to change them"
        )


def committed_benchmarks(results: Path) -> list[str]:
    """Every benchmark with a table under ``results`` (what ``--check`` checks by default)."""
    from zoo.evaluation.results import table_files
    from zoo.protocol.benchmark import list_benchmarks

    known = set(list_benchmarks())
    found = sorted(p.parent.parent.name for p in table_files(results, depth=2))
    unknown = sorted({b for b in found if b not in known})
    if unknown:
        raise UsageError(
            f"{results}: tables of unknown benchmark(s) {', '.join(unknown)} "
            f"(known: {', '.join(sorted(known))})"
        )
    return list(dict.fromkeys(found))


def default_benchmarks():
    """The main job: the embedded cloth benchmark (generated here, no download), plus CMU when
    its motion-capture files are present."""
    from zoo.protocol.benchmark import get_benchmark

    yield "cloth"
    cmu = get_benchmark("cmu")
    if cmu.resolve_data_root() is not None and cmu.resolve_data_root().is_dir():
        yield "cmu"
    else:
        print(
            f"note: CMU Mocap not found at {cmu.resolve_data_root()}; evaluating the cloth "
            f"benchmark only (zoo leaderboard --benchmark cmu --data-root PATH for CMU)",
            file=sys.stderr,
        )


def print_average(frame, horizons) -> None:
    from tabulate import tabulate

    from zoo.evaluation.markdown import default_horizons

    # a long-term run's horizons past the benchmark's last
    horizons = [*horizons, *(h for h in default_horizons(frame) if h > max(horizons))]
    avg = frame[(frame["action"] == "average") & frame["horizon_ms"].isin(horizons)]
    keys = ["model", "metric", "averaging", "joints"]
    table = avg.pivot_table(index=keys, columns="horizon_ms", values="value")
    print(
        tabulate(
            table.reset_index(),
            headers=keys + [f"{h} ms" for h in table.columns],
            tablefmt="github",
            floatfmt=".4g",
            showindex=False,
        )
    )
