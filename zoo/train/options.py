"""How a training run is carried out, beside what it trains (the model, its hyper-parameters and
its recipe): where it reads and writes, on which device and seed, how it starts and when it
stops. Checked when made, so a run that cannot start is refused before any data is read."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from zoo.core.errors import TrainingError


@dataclass(frozen=True)
class RunOptions:
    """``seed``: of the initial weights, the data order and dropout. ``data_root``: the
    benchmark's data (default: its own). ``out_dir``: the run folder (default:
    ``checkpoints/<benchmark>/<model>``). ``resume``: continue from the run's ``last.pt`` (or its
    committed paused state). ``init_from``: a checkpoint or shipped weights of the same model
    and protocol to start from, with a fresh optimiser and schedule (a further stage, recorded
    with the source's budget). ``max_batches``: cap the batches of an epoch. ``cuda_graph``: on
    one CUDA device (one process), capture each epoch's step once as a CUDA graph and replay it
    (:class:`zoo.train.step.CudaGraphStep`). ``compile``: run the training loss through
    ``torch.compile`` (the same model and recipe, float32 rounded as another CPU would; eager
    again, said once, where the compiler fails). ``stop_by`` (a ``time.time()``): the run ends by
    then, its last finished epoch on disk: an epoch that the longest so far says cannot finish
    in time is not begun, one that runs past it is abandoned (a lent machine's time limit).
    ``stop_after_epoch``: end the run after that epoch as if interrupted (tests of ``resume``)."""

    seed: int = 0
    device: str = "cpu"
    data_root: str | Path | None = None
    out_dir: str | Path | None = None
    resume: bool = False
    init_from: str | Path | None = None
    max_batches: int | None = None
    progress: bool = True
    cuda_graph: bool = False
    compile: bool = False
    stop_by: float | None = None
    stop_after_epoch: int | None = None

    def __post_init__(self) -> None:
        seed = self.seed
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**32:
            raise TrainingError(f"seed must be an integer in 0..2**32-1, got {seed!r}")
        batches = self.max_batches
        if batches is not None and (
            isinstance(batches, bool) or not isinstance(batches, int) or batches < 1
        ):
            raise TrainingError(
                f"max_batches: must be a positive integer, got {batches!r}",
                parameter="max_batches",
            )
        if self.compile and self.cuda_graph:
            raise TrainingError(
                "compile: give --compile or --cuda-graph, not both (a CUDA graph replays the "
                "eager step)",
                parameter="compile",
            )
        if self.init_from is not None and self.resume:
            raise TrainingError(
                "init_from: give init_from (a new stage from other weights) or resume (this "
                "run's last state), not both",
                parameter="init_from",
            )
