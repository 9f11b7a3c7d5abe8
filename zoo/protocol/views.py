"""What a model is fed and scored on: a benchmark's joints, the exp-map angles they were made
from, or its mesh's vertices, and the metrics the rows of each carry. A view is a ``str``
(``joints``, ``expmap``, ``mesh``), so the records and tables that name it keep the word."""

from __future__ import annotations

from enum import Enum

from zoo.protocol.metrics import METRICS, Metric


class View(str, Enum):
    """``joints``: a skeleton benchmark's joints, or, for a skeleton model on a mesh benchmark,
    the joints its regressor takes from the vertices; ``expmap``: the exp-map angles of every
    joint of a skeleton benchmark whose data has them, predicted angles scored on the joints
    forward kinematics makes of them; ``mesh``: the vertices themselves."""

    JOINTS = "joints"
    EXPMAP = "expmap"
    MESH = "mesh"

    def __str__(self) -> str:  # the word, as records and messages write it (Python 3.10 too)
        return self.value

    @property
    def metrics(self) -> tuple[Metric, ...]:
        """The metrics of its rows, in the order the evaluator scores them; a mesh model's MPJPE
        is on the joints its predicted vertices regress to (where the benchmark has a
        regressor: :meth:`zoo.protocol.metrics.BatchTruth.joint_errors` gives none otherwise)."""
        return tuple(METRICS[name] for name in _VIEW_METRICS[self])


_VIEW_METRICS = {
    View.JOINTS: ("mpjpe",),
    View.EXPMAP: ("mpjpe",),
    View.MESH: ("melv", "rmse", "mpjpe"),
}
