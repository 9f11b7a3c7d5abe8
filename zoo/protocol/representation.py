"""What a benchmark's points are, as one object: a skeleton's joints
(:mod:`zoo.protocol.joints`) or a mesh's vertices (:mod:`zoo.protocol.mesh`), each the one place
that knows, for its kind of data, what a loader must return, what a model is built with and
sees, how a protocol is planned and recorded, what its rows are scored against and which of
them heads a table, and what a training run trains on and records.

A benchmark names its representation by word (``representation: joints``);
:data:`zoo.protocol.benchmark.REPRESENTATIONS` maps the word to its object. A third kind of data
(hand keypoints, point clouds) is a third subclass there, not new branches elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch

from zoo.core.errors import EvaluationError
from zoo.data import windows as window_rules
from zoo.protocol.views import View


@dataclass(frozen=True)
class PlannedWindows:
    """A representation's part of a planned protocol: the windows scored (``index``: sequence
    and first frame of each, in scoring order; ``actions``: each window's), the record's own
    fields, and what its ground truth is (a mesh's: raw or spectral, its MELV frames and basis)."""

    index: np.ndarray
    actions: np.ndarray
    record: dict[str, Any]
    ground_truth: str | None = None
    melv_frames: str | None = None
    basis: Any = None


class Representation:
    """One kind of benchmark points. ``name``: the word a benchmark file and a model's registry
    entry write; ``dataset_type``: what a loader returns; ``fields``: the benchmark fields only
    this kind writes (their names in the file); ``drawn``: its frames are surfaces that ``zoo
    render`` and the site's clips draw; ``model_kinds``: the registry representations of models
    it feeds beside its own (a joints benchmark's exp-map angles)."""

    name: ClassVar[str]
    dataset_type: ClassVar[type]
    fields: ClassVar[tuple[str, ...]] = ()
    drawn: ClassVar[bool] = False
    model_kinds: ClassVar[tuple[str, ...]] = ()  # registry words of models it also feeds

    def __str__(self) -> str:
        return self.name

    # ---- the benchmark file and its data ------------------------------------------------------

    def check_fields(self, fields) -> None:
        """Refuse (``ValueError``) a benchmark file's fields that this kind cannot plan with."""

    def check_dataset(self, bench, dataset) -> None:
        """Refuse (``BenchmarkError``) what ``bench``'s loader returned, beyond its type."""

    def view_for(self, representations) -> View:
        """How a model whose registry ``representation`` lists ``representations`` sees it."""
        raise NotImplementedError

    def scored_kinds(self, dataset) -> tuple[str, ...]:
        """The registry representations whose models get rows on ``dataset``."""
        return (self.name,)

    def model_inputs(self, bench, context: tuple[str, ...], view: View, dataset) -> dict:
        """The constructor keywords a model of ``view`` gets (``dataset()``: the data, loaded
        only where the keywords need it)."""
        raise NotImplementedError

    # ---- a planned protocol and its scoring -----------------------------------------------------

    def ground_truths(self, bench) -> tuple[str | None, ...]:
        """The ground truths it can be scored against, one table each (None: the data's own)."""
        return (None,)

    def plan(self, bench, dataset, sampler: str, t_out: int, ground_truth, melv_frames):
        """The :class:`PlannedWindows` of ``sampler`` on ``dataset``, ``t_out`` frames
        predicted."""
        raise NotImplementedError

    def scoring(self, protocol, device) -> Scoring:
        """How the evaluator scores models on a planned ``protocol``."""
        raise NotImplementedError

    def headline(self, record: dict[str, Any]) -> tuple[str, str]:
        """The ``(metric, joints)`` the headline of a table of ``record`` reports."""
        raise NotImplementedError

    # ---- training -----------------------------------------------------------------------------

    def weights_protocol(self, bench, view: View) -> dict[str, Any]:
        """What weights trained on ``bench`` for ``view`` depend on, wherever they are scored:
        the benchmark, its data and window, and this kind's own (:meth:`weights_fields`)."""
        return {
            "benchmark": bench.name,
            "dataset": bench.dataset,
            "input_frames": bench.input_frames,
            "output_frames": bench.output_frames,
            **self.weights_fields(bench, view),
        }

    def weights_fields(self, bench, view: View) -> dict[str, Any]:
        """This kind's part of :meth:`weights_protocol`."""
        raise NotImplementedError

    def training_data(self, dataset, view: View):
        """The dataset a model of ``view`` trains on, and which of its points it predicts."""
        raise NotImplementedError

    def training_record(self, dataset, view: View) -> dict[str, Any]:
        """What a run's record says of the data a model of ``view`` trained on (``dataset``,
        from :meth:`training_data`)."""
        raise NotImplementedError

    def training_points(self, dataset, view: View):
        """How validation turns windows of :meth:`training_data`'s frames into the points it
        scores (``None``: as they are)."""
        return None

    def validation_curve(self, view: View) -> str:
        """The metric of a training run's validation curve (its horizons, in the log and the
        epoch record): the headline's."""
        return "mpjpe"

    # ---- shared by the kinds ------------------------------------------------------------------

    @staticmethod
    def windows(bench, dataset, sampler: str, t_out: int, rule, subactions=None):
        """The windows ``sampler`` takes from ``dataset`` and each one's action."""
        sequences = dataset.sequences
        index = window_rules.window_sampler(
            sampler,
            [len(s) for s in sequences],
            bench.input_frames,
            t_out,
            rule,
            groups=[s.action for s in sequences],
            **({"subactions": subactions} if subactions is not None else {}),
        )
        return index, np.asarray([sequences[i].action for i in index[:, 0]])


class Scoring:
    """How one planned protocol scores models, batch after batch: what each view of a model is
    fed, and what its predictions are scored against."""

    def check_view(self, view, name: str) -> None:
        """Refuse (``EvaluationError``) model ``name`` fed ``view`` here."""
        raise NotImplementedError

    def batch_size(self, asked: int) -> int:
        return asked

    def truth(self, index: np.ndarray, views: set[View]) -> TruthBatch:
        """The ground truth of the windows ``index``, for models of ``views``."""
        raise NotImplementedError

    def recorded(self, view: View, model) -> dict[str, Any]:
        """What a result of ``model`` fed ``view`` records beside the protocol."""
        return {}


class TruthBatch:
    """One batch of ground-truth windows: what a model of each view reads (``observed``) and
    what its predictions are scored against (``scored_as``, a
    :class:`zoo.protocol.metrics.BatchTruth`), with the data's own errors (``own_errors``)."""

    def observed(self, view: View) -> tuple[torch.Tensor, torch.Tensor]:
        """The observed frames a model of ``view`` reads, and the windows' last frame."""
        raise NotImplementedError

    def scored_as(self, view: View):
        raise NotImplementedError

    def floor_target(self, view: View) -> torch.Tensor | None:
        """The future a model's autoencoder floor passes through (None: the protocol records
        no floor rows for models of ``view``)."""
        return None

    def own_errors(self, view: View) -> dict:
        """Rows of the data itself, beside each model of ``view`` (none by default)."""
        return {}


class JointsTruth:
    """Ground-truth joints (``target``: the future) that predicted joints are scored against,
    under the benchmark's joint protocols (``errors(pred, target)``)."""

    reference_lengths = None

    def __init__(self, target: torch.Tensor, errors) -> None:
        self.target, self._errors = target, errors

    def joint_errors(self, pred: torch.Tensor) -> dict[str, torch.Tensor]:
        return self._errors(pred, self.target)

    def melv_lengths(self, frames: torch.Tensor) -> torch.Tensor:
        raise EvaluationError("joints have no edges to measure MELV on")
