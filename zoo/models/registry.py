"""The model registry: ``registry.yaml`` entries turned into models.

``list_models()`` and ``create_model(name, **overrides)`` in the style of timm. Further registry
files (a user's own baselines, outside ``zoo/``) join through ``load_registry(path, ...)``, the
``ZOO_REGISTRY`` environment variable (paths separated by ``os.pathsep``) or ``--registry`` on the
command line. A class is named ``package.module.Class`` or ``path/to/file.py:Class`` (a path
relative to the registry file that names it).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import inspect
import os
import re
import sys
import weakref
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import pydantic
import yaml
from pydantic import BeforeValidator, ConfigDict, Field, StrictBool

from zoo.core.definitions import DefinitionError, load_definition
from zoo.core.errors import TrainingError, ZooError
from zoo.core.files_read import recording_files_read
from zoo.core.io import load_yaml, yaml_problem
from zoo.core.schema import line_of, validated
from zoo.models.citation import Paper, Url
from zoo.paths import REPO_ROOT

DEFAULT_REGISTRY = REPO_ROOT / "registry.yaml"
# The words of zoo.protocol.benchmark.MODEL_REPRESENTATIONS, written here because reading a
# registry (``zoo --help`` does) loads no torch; tests/test_representations.py holds them equal.
ModelRepresentation = Literal["joints", "expmap", "mesh"]
# Keywords every model receives from the benchmark (see zoo.models).
SHAPE_ARGS = ("input_frames", "output_frames", "num_points")
# The data files a model's constructor read while it was built: an author's weights loaded in a
# wrapper's __init__ are part of what its results are. Kept per class and keywords for the
# process, so a second build that a cache spares the reading records the same files.
_ZOO_CODE = (REPO_ROOT / "zoo",)
_READ_BY_BUILD: dict[tuple, frozenset[Path]] = {}
_READ_WHILE_BUILT: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def files_read_while_built(model) -> frozenset[Path]:
    """The data files (resolved) that ``model``'s constructor opened while
    :meth:`Registry.create_model` built it (or an earlier build of its class with the same
    keywords, in this process); empty for a model built otherwise."""
    return _READ_WHILE_BUILT.get(model, frozenset())


class RegistryError(ZooError, KeyError):
    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])


class UnknownModelError(RegistryError):
    """A model name no loaded registry defines (``model``: the name asked for)."""

    def __init__(self, message: str, model: str) -> None:
        super().__init__(message)
        self.model = model


def _one_or_more(value: Any) -> Any:
    return (value,) if isinstance(value, str) else value


def _none_is_empty(value: Any) -> Any:
    return {} if value is None else value


def _stripped(value: Any) -> Any:
    return value.strip() if isinstance(value, str) else value


@pydantic.dataclasses.dataclass(frozen=True, config=ConfigDict(extra="forbid"))
class EntryFields:
    """A registry entry as its file writes it (``models: {name: entry}``): the schema the file
    is read through (zoo.core.schema), each field once."""

    class_path: str = Field(alias="class")  # module.Class or file.py:Class
    representation: Annotated[
        tuple[ModelRepresentation, ...], Field(min_length=1), BeforeValidator(_one_or_more)
    ] = Field()
    trainable: StrictBool = False
    hparams: Annotated[dict[str, Any], BeforeValidator(_none_is_empty)] = field(
        default_factory=dict
    )
    reference: Annotated[str, BeforeValidator(_stripped)] = ""
    context: Annotated[tuple[str, ...], BeforeValidator(lambda v: v or ())] = ()
    description: Annotated[str, BeforeValidator(_stripped)] = ""
    # the training recipe (zoo.models.recipe, checked where the registry is read); None: it
    # learns, but has no recipe here yet (its weights come from elsewhere, zoo weights import)
    train: dict[str, Any] | None = field(default_factory=dict)
    # What its forward does: prediction ``forward(history)``, or completion
    # ``forward(history, final_frame)`` (the window's last frame given). Tables keep them apart.
    task: Literal["prediction", "completion"] = Field("prediction", validate_default=True)
    override: StrictBool = False  # replaces an entry of the same name from an earlier file
    # False: scored on demand (zoo eval, zoo.evaluate, the coverage benchmark), never a row of
    # the committed leaderboards, whose untrained rows are the protocol's own baselines.
    leaderboard: StrictBool = True
    # An inference-only variant: runs the trained weights of that entry (shipped or in
    # checkpoints/) through its own class, with that entry's hyper-parameters.
    weights_of: str = ""
    paper: Paper | None = None  # the paper it reproduces (links and BibTeX: zoo.models.citation)
    code: Url = ""  # the address of its authors' public code

    @pydantic.field_validator("hparams")
    @classmethod
    def _not_the_benchmarks(cls, hparams: dict[str, Any]) -> dict[str, Any]:
        clash = sorted(set(hparams) & set(SHAPE_ARGS))
        if clash:
            raise ValueError(f"{', '.join(clash)} come from the benchmark, not hparams")
        return hparams

    @pydantic.field_validator("task")
    @classmethod
    def _as_hparams_say(cls, task: str, info: pydantic.ValidationInfo) -> str:
        said = info.data.get("hparams", {}).get("task", task)
        if said != task:
            raise ValueError(
                f"the entry's task is {task!r} but hparams say task {said!r}; they must agree"
            )
        return task

    @pydantic.field_validator("weights_of")
    @classmethod
    def _not_trained(cls, weights_of: str, info: pydantic.ValidationInfo) -> str:
        if weights_of and info.data.get("trainable"):
            raise ValueError(
                f"an entry that runs another's weights is not trainable: it is trained as that "
                f"one (zoo train --model {weights_of})"
            )
        return weights_of


@dataclass(frozen=True, kw_only=True)
class ModelEntry(EntryFields):
    """A registry entry as the registry holds it: its fields, its name and its file."""

    name: str
    source: Path
    replaces: str = ""  # the registry file whose entry of this name it overrides, if any

    def provenance(self) -> dict[str, str]:
        """What every result of this model records about where it came from."""
        from zoo.core.io import registry_record

        return {
            "class": self.class_path,
            "registry": registry_record(self.source),
            **({"replaces": self.replaces} if self.replaces else {}),
        }

    @property
    def class_name(self) -> str:
        """The class's own name, without the module or file that holds it: what an identity
        records, so that moving the class re-stamps nothing (its code is fingerprinted)."""
        return class_name(self.class_path)

    @property
    def valid_args(self) -> list[str]:
        return sorted(set(self.hparams) | set(SHAPE_ARGS) | set(self.context))

    def load_class(self) -> type:
        try:
            return load_definition(self.class_path, self.source.parent, "class")
        except DefinitionError as e:
            raise RegistryError(f"{self.source}: model {self.name!r}: {e}") from e


def class_name(class_path: str) -> str:
    """``SPGSN`` of ``zoo.models.spgsn.SPGSN`` or ``wrapper.py:Wrapper``."""
    return re.split(r"[.:]", class_path)[-1]


def _registry_file_data(path: Path) -> Any:
    """A registry file's YAML as data: a copy of the parse kept for that text, since a command
    loads the registry many times (every table, every plot) and the parse is most of a load."""
    return copy.deepcopy(_parsed_yaml(path.read_text()))


@functools.lru_cache(maxsize=16)
def _parsed_yaml(text: str) -> Any:
    return load_yaml(text)


class Registry:
    def __init__(self, entries: dict[str, ModelEntry] | None = None) -> None:
        self.entries: dict[str, ModelEntry] = dict(entries or {})

    @classmethod
    def from_files(cls, *paths: str | Path) -> Registry:
        registry = cls()
        for path in paths:
            registry.add_file(path)
        return registry

    def add_file(self, path: str | Path) -> None:
        path = Path(path)
        if not path.is_file():
            raise RegistryError(f"registry file {path} does not exist")
        try:
            data = _registry_file_data(path) or {}
        except yaml.YAMLError as e:
            raise RegistryError(f"{path}: not valid YAML: {yaml_problem(e)}") from e
        models = data.get("models") if isinstance(data, dict) else None
        if not isinstance(models, dict):
            raise RegistryError(f"{path}: expected a top-level mapping 'models: {{name: entry}}'")
        for name, raw in models.items():
            entry = _parse_entry(path, name, raw)
            previous = self.entries.get(name)
            if previous is not None:
                # A second model under a known name would publish rows under the first one's
                # name and protocol: only an explicit override may, and its results say so.
                if not entry.override:
                    raise RegistryError(
                        f"{path}, line {line_of(path, ('models', name))}: model {name!r} is "
                        f"already defined in "
                        f"{previous.source}; choose another name, or add "
                        f"'override: true' to this entry to replace it"
                    )
                entry = dataclasses.replace(entry, replaces=str(previous.source))
            self.entries[name] = entry
        for entry in self.entries.values():
            if entry.weights_of and entry.source == path:
                self._check_weights_of(entry)

    def _check_weights_of(self, entry: ModelEntry) -> None:
        """An entry that runs another's weights names a trainable model defined before it (in
        its file or an earlier one) that sees the same data: task, representation, context."""
        target = self.entries.get(entry.weights_of)
        if target is None:
            problem = (
                f"{entry.weights_of!r} is not a registered model (it must be defined in this "
                f"registry file or an earlier one)"
            )
        elif not target.trainable:
            problem = f"{entry.weights_of!r} is not trainable, so it has no weights to run"
        else:
            problem = next(
                (
                    f"its {name} {getattr(entry, name)!r} differs from {entry.weights_of!r}'s "
                    f"{getattr(target, name)!r}; an entry runs only weights trained for what it "
                    f"sees"
                    for name in ("task", "representation", "context")
                    if getattr(entry, name) != getattr(target, name)
                ),
                None,
            )
        if problem is not None:  # the file is read again for the line only where it is wrong
            line = line_of(entry.source, ("models", entry.name, "weights_of"))
            raise RegistryError(
                f"{entry.source}, line {line}: model {entry.name!r}: field 'weights_of': {problem}"
            )

    def list_models(self, representation: str | None = None) -> list[str]:
        return sorted(
            n
            for n, e in self.entries.items()
            if representation is None or representation in e.representation
        )

    def get(self, name: str) -> ModelEntry:
        if name not in self.entries:
            import difflib

            close = difflib.get_close_matches(str(name), self.list_models(), n=3, cutoff=0.6)
            hint = f"did you mean {' or '.join(close)}? " if close else ""
            raise UnknownModelError(
                f"unknown model {name!r}; {hint}registered models: {', '.join(self.list_models())}",
                str(name),
            )
        return self.entries[name]

    def model_args(self, name: str, **overrides: Any) -> dict[str, Any]:
        """The full constructor keywords: registry defaults updated by ``overrides``."""
        entry = self.get(name)
        unknown = sorted(set(overrides) - set(entry.valid_args))
        if unknown:
            supplied = [*SHAPE_ARGS, *entry.context]
            raise RegistryError(
                f"model {name!r} has no hyper-parameter "
                f"{', '.join(map(repr, unknown))}; its hyper-parameters: "
                f"{', '.join(sorted(entry.hparams)) or 'none'} ({', '.join(supplied)} come from "
                f"the benchmark)"
            )
        args = {**entry.hparams, **overrides}
        missing = [a for a in (*SHAPE_ARGS, *entry.context) if a not in args]
        if missing:
            raise RegistryError(
                f"model {name!r} needs {', '.join(missing)}, which a benchmark "
                f"supplies: create_model({name!r}, benchmark='cmu') or pass them"
            )
        return args

    def create_model(self, name: str, **overrides: Any):
        entry = self.get(name)
        args = self.model_args(name, **overrides)
        cls = entry.load_class()
        params = inspect.signature(cls).parameters
        takes_any = any(p.kind is p.VAR_KEYWORD for p in params.values())
        unused = [a for a in args if a not in params and not takes_any]
        if unused:
            raise RegistryError(
                f"{entry.source}: model {name!r}: class {entry.class_path} does "
                f"not accept {', '.join(unused)}"
            )
        try:
            with recording_files_read(_ZOO_CODE) as read:
                model = cls(**args)
        except (ValueError, TypeError) as e:
            if cls.__module__.split(".")[0] == "zoo":
                # the zoo's own models check their arguments: the message is the answer
                raise RegistryError(f"model {name!r}: {e}") from e
            # a user's model keeps its traceback (it is their code), introduced by one line
            print(
                f"zoo: model {name!r} ({entry.class_path}, registry {entry.source}) raised "
                f"while being built:",
                file=sys.stderr,
            )
            raise
        key = (cls.__module__, cls.__qualname__, repr(sorted(args.items(), key=lambda kv: kv[0])))
        _READ_BY_BUILD[key] = _READ_BY_BUILD.get(key, frozenset()) | frozenset(read)
        _READ_WHILE_BUILT[model] = _READ_BY_BUILD[key]
        return model


def _parse_entry(path: Path, name: str, raw: Any) -> ModelEntry:
    where = f"model {name!r}: "
    # Names become folder and file names (results/<benchmark>/<sampler>/<name>/).
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.-]*", name):
        raise RegistryError(
            f"{path}, line {line_of(path, ('models', name))}: {where}a model name is letters, "
            f"digits, '_', '.' and '-', not starting with '.' or '-' (it names result folders)"
        )
    at = ("models", name)
    fields = validated(EntryFields, raw, path, at, where, RegistryError)
    if fields.weights_of == name:
        raise RegistryError(
            f"{path}, line {line_of(path, (*at, 'weights_of'))}: {where}field 'weights_of' "
            f"names another model whose trained weights this one runs, not itself"
        )
    if fields.train is not None:  # a bad recipe is refused at zoo list, not at zoo train
        from zoo.models.recipe import training_recipe

        try:
            training_recipe(fields.train, path=path, at=(*at, "train"), what=where)
        except TrainingError as e:
            raise RegistryError(str(e)) from None
    values = {f.name: getattr(fields, f.name) for f in dataclasses.fields(EntryFields)}
    return ModelEntry(**values, name=name, source=path)


def load_registry(*extra: str | Path) -> Registry:
    """The project's registry plus ``ZOO_REGISTRY`` files plus ``extra`` (later ones win)."""
    if not DEFAULT_REGISTRY.is_file():
        raise RegistryError(
            f"{DEFAULT_REGISTRY} not found: install motion-zoo from its source "
            f"tree (pip install -e .) so the registry travels with the code"
        )
    env = [p for p in os.environ.get("ZOO_REGISTRY", "").split(os.pathsep) if p]
    return Registry.from_files(DEFAULT_REGISTRY, *env, *extra)


def as_registry(registry: Registry | str | Path | list | tuple | None, what: str) -> Registry:
    """What an API function's ``registry=`` may be: a :class:`Registry`, the path of a registry
    file or a list of them (added to the project's, as ``--registry`` adds them), or None (the
    project's); anything else is refused naming ``what``."""
    if registry is None:
        return load_registry()
    if isinstance(registry, Registry):
        return registry
    files = [registry] if isinstance(registry, (str, Path)) else registry
    if not isinstance(files, (list, tuple)) or not all(isinstance(f, (str, Path)) for f in files):
        raise RegistryError(
            f"{what}: registry must be a zoo.Registry or the path of a registry file (or a list "
            f"of them), got {type(registry).__name__}"
        )
    missing = [str(f) for f in files if not Path(f).is_file()]
    if missing:
        raise RegistryError(f"{what}: registry file {missing[0]} does not exist")
    return load_registry(*files)
