"""One optimizer step, as the engine runs it and the cost columns time it: the training loss
(a model's own or mean MPJPE), its precision, the optimizer and its learning rate, and the step
captured as a CUDA graph."""

from __future__ import annotations

import torch
from torch import nn

from zoo.core.errors import TrainingError
from zoo.evaluation.evaluator import predict
from zoo.models.hooks import model_hooks
from zoo.models.recipe import PRECISIONS, Recipe
from zoo.protocol.metrics import mpjpe
from zoo.train.host import precision_on


def forward_precision(precision: str, device) -> torch.autocast:
    """The context a training loss runs in for recipe ``precision`` (``PRECISIONS``, or
    ``auto`` as this machine takes it): an autocast to its dtype, or a disabled one for
    float32."""
    dtype = PRECISIONS[precision_on(precision, device)]
    return torch.autocast(torch.device(device).type, dtype=dtype, enabled=dtype is not None)


class TrainingObjective(nn.Module):
    """The training loss as a module, so DDP synchronises gradients of any model's own loss:
    with ``view``, the model's ``training_loss_view`` of windows of its training view; else its
    ``training_loss`` if it defines one, else mean MPJPE over predicted frames (a completion
    model is given the window's last frame)."""

    def __init__(self, model: nn.Module, task: str = "prediction", view: bool = False) -> None:
        super().__init__()
        self.model, self.task, self.view = model, task, view
        self.own_loss = model_hooks(model).training_loss

    def forward(self, history: torch.Tensor, future: torch.Tensor) -> torch.Tensor:
        if self.view:  # windows of the model's own training view
            return self.model.training_loss_view(history, future)
        if self.own_loss:
            return self.model.training_loss(history, future)
        pred = predict(self.model, history, self.task, future.shape[1], future[:, -1])
        return mpjpe(pred, future).mean()


def prepare_epoch(model: nn.Module, epoch: int, frames, view: bool = False) -> None:
    """A model's ``start_epoch`` hook for ``epoch``, where it has one, as the engine runs it
    before each epoch: ``frames()`` yields ``(frames, counts)``, in the model's training view
    with ``view`` (only then is the hook given ``view=True``: a model without a view need not
    take it)."""
    if not model_hooks(model).start_epoch:
        return
    if view:
        model.start_epoch(epoch, frames, view=True)
    else:
        model.start_epoch(epoch, frames)


def training_step(
    objective: nn.Module,
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    history: torch.Tensor,
    future: torch.Tensor,
    recipe: Recipe,
    device,
    where: str = "{loss}",
    check_finite: bool = True,
) -> torch.Tensor:
    """One optimizer step, as the engine runs it and the cost columns time it: the loss
    (``objective``, in the recipe's precision), refused where it is not finite, its gradients,
    the recipe's gradient clip on ``model``'s parameters, and the step. Returns the loss.
    ``where`` says where a non-finite loss happened, ``{loss}`` standing for "loss is <value>".
    ``check_finite=False`` leaves that check to the caller (a CUDA graph cannot stop to look)."""
    with forward_precision(recipe.precision, device):
        loss = objective(history, future)
    if check_finite:
        refuse_non_finite(loss, where)
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    if recipe.grad_clip:
        nn.utils.clip_grad_norm_(model.parameters(), recipe.grad_clip)
    optimizer.step()
    return loss


def refuse_non_finite(loss: torch.Tensor, where: str) -> None:
    if not torch.isfinite(loss):
        raise TrainingError(
            where.format(loss=f"loss is {loss.item()}")
            + ": training stopped (lower the lr or check the data)"
        )


def make_optimizer(
    model: nn.Module, recipe: Recipe, device, graphed: bool = False
) -> torch.optim.Optimizer:
    """The recipe's Adam; for a CUDA graph, capturable, its learning rate a device tensor that
    :func:`set_learning_rate` changes in place (a float would be frozen into the graph)."""
    lr = torch.tensor(recipe.lr, device=device) if graphed else recipe.lr
    return torch.optim.Adam(
        model.parameters(), lr=lr, weight_decay=recipe.weight_decay, capturable=graphed
    )


def optimizer_for_device(optimizer: torch.optim.Optimizer, device, graphed: bool) -> None:
    """After ``load_state_dict``: the loaded groups' learning rate and ``capturable`` as
    :func:`make_optimizer` sets them for this run, the step counters where Adam expects them (on
    the device when capturable, else on the CPU), so a run written on a GPU resumes on a CPU and
    the other way round."""
    for group in optimizer.param_groups:
        lr = float(group["lr"])
        group["lr"] = torch.tensor(lr, device=device) if graphed else lr
        group["capturable"] = graphed
    for state in optimizer.state.values():
        if torch.is_tensor(state.get("step")):
            state["step"] = state["step"].to(device if graphed else "cpu", torch.float32)


def set_learning_rate(optimizer: torch.optim.Optimizer, lr: float) -> None:
    for group in optimizer.param_groups:
        if torch.is_tensor(group["lr"]):
            group["lr"].fill_(lr)
        else:
            group["lr"] = lr


class CudaGraphStep:
    """:func:`training_step` on a CUDA device, captured once as a CUDA graph and replayed.

    A small model's step is thousands of tiny kernels whose launches, not their arithmetic,
    take the time (PGBIG: about 2,000 a step at batch 16); a graph launches them all at once.
    The first :attr:`WARMUP` calls are ordinary steps on a side stream (they build Adam's state
    and let the libraries pick their kernels), the next one captures the step and every call
    from then on copies its batch into the graph's inputs and replays it: the same step, the
    same arithmetic. A non-finite loss is refused after its replay (the step is already taken;
    the checkpoints on disk are the last finished epoch's). The batch must keep its shape, and
    what the step does must not change while it is replayed (the engine captures one per
    epoch). A step that cannot be captured (one that reads a value back to decide what to do)
    is refused, naming why: the run stops there, its last finished epoch on disk."""

    WARMUP = 3

    def __init__(self, objective, model, optimizer, recipe, device) -> None:
        self.args = (objective, model, optimizer)
        self.recipe, self.device = recipe, device
        self.calls = 0
        self.graph: torch.cuda.CUDAGraph | None = None
        self.side = torch.cuda.Stream(device)

    def __call__(self, history: torch.Tensor, future: torch.Tensor, where: str) -> torch.Tensor:
        with torch.cuda.device(self.device):  # cuda:N: capture and replay there, not on cuda:0
            return self._step(history, future, where)

    def _step(self, history: torch.Tensor, future: torch.Tensor, where: str) -> torch.Tensor:
        self.calls += 1
        if self.calls <= self.WARMUP:
            self.side.wait_stream(torch.cuda.current_stream(self.device))
            with torch.cuda.stream(self.side):
                loss = training_step(*self.args, history, future, self.recipe, self.device, where)
            torch.cuda.current_stream(self.device).wait_stream(self.side)
            return loss
        if self.graph is None:
            self.history, self.future = history.clone(), future.clone()
            self.graph = torch.cuda.CUDAGraph()
            try:
                with torch.cuda.graph(self.graph):
                    self.loss = training_step(
                        *self.args,
                        self.history,
                        self.future,
                        self.recipe,
                        self.device,
                        check_finite=False,
                    )
            except RuntimeError as e:
                raise TrainingError(
                    f"{where.split(':')[0]}: its training step cannot be captured as a CUDA "
                    f"graph ({str(e).splitlines()[0][:200]}); train without cuda_graph"
                ) from None
        else:
            self.history.copy_(history)
            self.future.copy_(future)
        self.graph.replay()
        refuse_non_finite(self.loss, where)
        return self.loss
