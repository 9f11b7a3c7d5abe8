"""One path from a model to a stored result, shared by ``zoo eval``, ``zoo.evaluate`` and
``zoo leaderboard`` (nothing else orchestrates an evaluation): the subject (:class:`Subject`),
its place checked (:func:`place`), the evaluation (:func:`compute`, :func:`compute_all`) and the
result stored (:func:`store`); ``zoo eval`` and ``zoo.evaluate`` take all of it in one call
(:func:`evaluate_and_store`).
docs/architecture.md ("The path of one result") walks through it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from torch import nn

from zoo.core.io import check_output_folder
from zoo.core.options import EVAL_BATCH
from zoo.evaluation import evaluator
from zoo.evaluation.evaluator import Scored, evaluate_models
from zoo.evaluation.results import EvalResult
from zoo.evaluation.tolerance import Agreement, agreement
from zoo.protocol.plan import Protocol
from zoo.protocol.views import View
from zoo.store.identity import check_replace, evaluation_code, stamp


def row_code(model_class: type | None, bench) -> dict[str, str | None]:
    """The code a row's identity covers: the evaluator this layer runs (zoo.evaluation.evaluator
    and the zoo modules it imports that compute numbers), the code that loads ``bench``'s data,
    and the model's class (:func:`zoo.store.identity.evaluation_code`)."""
    return evaluation_code(Path(evaluator.__file__), model_class, bench)


def row_identity(loaded, bench, protocol_id: str) -> dict[str, Any]:
    """The identity of a loaded model's results under ``protocol_id`` of ``bench``."""
    return loaded.identity(bench, protocol_id, row_code(type(loaded.model), bench))


@dataclass
class Subject:
    """The model a result is about: the module, its row label, what it is fed (``view``: mesh
    or joints), what its results record about it, and its identity under a protocol."""

    model: nn.Module
    label: str
    view: View
    provenance: dict[str, Any]
    identity_under: Callable[[Protocol], dict[str, Any]]
    # the observed frames it was built to read (None: all a protocol gives) and the length it
    # pads them to itself (hyper-parameter ``history_frames``, docs/adding-a-model.md)
    history_frames: int | None = None
    padded_to: int | None = None

    def scored(self) -> Scored:
        """What the evaluator scores: the module, under its label, fed its view (the last
        ``history_frames`` observed frames)."""
        return Scored(
            self.model, self.label, self.view, self.provenance, self.history_frames, self.padded_to
        )

    @classmethod
    def of_loaded(cls, loaded) -> Subject:
        """A model from :meth:`zoo.hub.model_source.ModelSource.load`."""
        return cls(
            loaded.model,
            loaded.label,
            loaded.view,
            _jsonable(loaded.provenance),
            lambda protocol: row_identity(loaded, protocol.benchmark, protocol.id),
            loaded.frames_read,
            loaded.hparams.get("history_frames"),
        )

    @classmethod
    def of_module(cls, model: nn.Module, label: str, view: View | str) -> Subject:
        """A module handed over from Python (no registry): its class, settings and weights."""
        from zoo.hub.model_source import object_identity

        return cls(
            model,
            label,
            view,
            {"class": f"{type(model).__module__}.{type(model).__qualname__}"},
            lambda protocol: object_identity(
                model,
                label,
                protocol.benchmark,
                protocol.id,
                row_code(type(model), protocol.benchmark),
            ),
        )


def _jsonable(value):
    """``value`` as JSON holds it (anything else by its repr)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    return repr(value)


@dataclass
class Place:
    """Where a result goes (or None: nothing written), the identity it will carry and what is
    stored there now (:func:`zoo.store.identity.check_replace`: new, same or replace)."""

    folder: Path | None
    identity: dict[str, Any]
    status: str = "new"


def place(
    subject: Subject, protocol: Protocol, folder: str | Path | None, replace: bool = False
) -> Place:
    """Check, before anything is evaluated, that ``folder`` may receive this result."""
    identity = subject.identity_under(protocol)
    if folder is None:
        return Place(None, identity)
    folder = Path(folder)
    check_output_folder(folder)
    return Place(folder, identity, check_replace(folder, identity, replace, protocol.record))


def plan_places(
    subject: Subject,
    bench,
    dataset,
    samplers: list[str | None],
    *,
    task: str = "prediction",
    horizon: int | None = None,
    ground_truth: str | None = None,
    melv_frames: str | None = None,
    out: str | Path | None = None,
    results: str | Path | None = None,
    write: bool = True,
    replace: bool = False,
) -> list[tuple[Protocol, Place]]:
    """Each sampler's protocol and its result's place, every place checked before anything is
    evaluated: ``out`` where given; otherwise ``<results>/<benchmark>/<table>/<label>/`` when
    ``write``, and no place (nothing stored) when not."""
    from zoo.protocol.plan import plan_protocol
    from zoo.store.layout import result_path, table_folder

    # Only a MELV other than the benchmark's default gets a table folder of its own.
    melv = melv_frames if melv_frames not in (None, getattr(bench, "melv_on", None)) else None
    plans = []
    for sampler in samplers:
        protocol = plan_protocol(
            bench,
            dataset,
            sampler=sampler,
            task=task,
            horizon=horizon,
            ground_truth=ground_truth,
            melv_frames=melv_frames,
        )
        folder = Path(out) if out is not None else None
        if folder is None and write:
            table = table_folder(protocol.sampler, task, ground_truth, horizon, melv)
            folder = result_path(results, bench.name, table, subject.label)
        plans.append((protocol, place(subject, protocol, folder, replace=replace)))
    return plans


def compute(
    subject: Subject,
    protocol: Protocol,
    identity: dict[str, Any],
    *,
    made_by: str,
    device: str = "cpu",
    batch_size: int = EVAL_BATCH,
) -> EvalResult:
    """The subject evaluated on the protocol's windows, its identity and maker stamped."""
    (result,) = compute_all(
        [(subject, identity)],
        protocol,
        made_by=made_by,
        device=device,
        batch_size=batch_size,
        keep_going=False,
    )
    return result


def compute_all(
    subjects: list[tuple[Subject, dict[str, Any]]],
    protocol: Protocol,
    *,
    made_by: str,
    device: str = "cpu",
    batch_size: int = EVAL_BATCH,
    keep_going: bool = True,
) -> list[EvalResult | Exception]:
    """Subjects (each with its identity) evaluated in one pass over the protocol's windows
    (:func:`zoo.evaluation.evaluator.evaluate_models`: the ground truth prepared once for all), each
    result stamped as :func:`compute` stamps it; a subject that failed gets its error instead (or,
    with ``keep_going=False``, the first failure is raised at once)."""
    results = evaluate_models(
        [subject.scored() for subject, _ in subjects],
        protocol,
        batch_size=batch_size,
        device=device,
        keep_going=keep_going,
    )
    for i, (result, (_, identity)) in enumerate(zip(results, subjects)):
        if isinstance(result, Exception):
            continue
        try:
            stamp(result, identity, made_by=made_by)
        except Exception as e:
            if not keep_going:
                raise
            results[i] = e
    return results


def evaluate_and_store(
    subject: Subject,
    bench,
    dataset,
    samplers: list[str | None],
    *,
    made_by: str,
    device: str = "cpu",
    batch_size: int = EVAL_BATCH,
    writes: bool = True,
    **where: Any,
) -> Iterator[tuple[EvalResult, Place, Stored | None]]:
    """The one path from plan to stored result, which ``zoo eval`` and ``zoo.evaluate`` both
    take: every sampler's place checked before anything is evaluated (:func:`plan_places`,
    ``where`` its keywords), then each evaluated (:func:`compute`) and, where it has a place
    and ``writes`` (the first process under torchrun), stored (:func:`store`). Yields each
    result, its place and what storing did (None: nothing stored)."""
    plans = plan_places(subject, bench, dataset, samplers, **where)
    for protocol, place_of in plans:
        result = compute(
            subject,
            protocol,
            place_of.identity,
            made_by=made_by,
            device=device,
            batch_size=batch_size,
        )
        stored = store(result, place_of) if writes and place_of.folder is not None else None
        yield result, place_of, stored


@dataclass
class Stored:
    """What :func:`store` did: ``written`` (nothing of this identity was there), ``kept`` (the
    stored result agrees: its files untouched) or ``rewritten`` (it differed beyond tolerance,
    or could not be read: ``agreed.why``)."""

    action: str
    agreed: Agreement | None = None


def store(result: EvalResult, where: Place) -> Stored:
    """Write ``result`` to ``where.folder``, unless the result stored there of the same
    identity agrees with it within the tolerance."""
    agreed = None
    if where.status == "same":
        agreed = agreement(result, where.folder)
        if agreed.same:
            return Stored("kept", agreed)
    result.write(where.folder)
    return Stored("rewritten" if agreed is not None else "written", agreed)
