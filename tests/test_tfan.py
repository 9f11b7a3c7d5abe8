"""TFAN (zoo.models.tfan): its size, its fusion rule by hand, its padding of a short history, its
bone tree refused where it is not a tree, and its training in the code's stages. Its equality
with the public code under the authors' weights is measured by benchmarks/speed/public_tfan.py
(docs/models/tfan.md)."""

from __future__ import annotations

import re

import pytest
import torch

import zoo
from zoo.models.history import pad_history
from zoo.models.tfan import TFAN


def _model(benchmark: str = "cmu50") -> TFAN:
    torch.manual_seed(0)
    model = zoo.create_model("tfan", benchmark=benchmark).eval()
    with torch.no_grad():  # the near-zero initial layers drawn at random, so every path counts
        for p in model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    return model


def test_size_and_shapes_as_the_public_code():
    model = _model()
    # two predictors of 136,200 and a gate of 302, as the code's three CMU state dicts
    assert sum(p.numel() for p in model.position.parameters()) == 136_200
    assert sum(p.numel() for p in model.gate.parameters()) == 302
    history = 300 * torch.randn(2, 50, 25, 3)
    assert model(history).shape == (2, 25, 25, 3)


def test_a_short_history_is_padded_with_its_oldest_frame():
    long, short = _model("cmu50"), _model("cmu")
    history = 300 * torch.randn(2, 10, 25, 3)
    with torch.no_grad():
        padded = long(pad_history(history, 50))
        torch.testing.assert_close(short(history), padded)


def test_fusion_chains_each_bone_onto_its_parent_as_gated():
    model = _model()
    bones = torch.randn(1, 1, 25, 3)
    positions = torch.randn(1, 1, 25, 3)
    layout = model.layout.tolist()
    # alpha 1, beta 0: a joint is its bone added to its parent's predicted position
    out = model.fuse(bones, positions, torch.tensor([[[1.0, 0.0]]]))
    parent, child = 9, 13  # thorax -> left shoulder, bone 10 of the registry's list
    i = layout.index(child)
    torch.testing.assert_close(out[0, 0, child], bones[0, 0, i] + positions[0, 0, parent])
    # a root is the mean of its two predictions
    torch.testing.assert_close(out[0, 0, 0], (bones[0, 0, 0] + positions[0, 0, 0]) / 2)
    # beta 1: every joint below the roots is its predicted position
    out = model.fuse(bones, positions, torch.tensor([[[0.3, 1.0]]]))
    children = [j for j in range(25) if j not in (0, 4, 8)]
    torch.testing.assert_close(out[0, 0, children], positions[0, 0, children])
    # alpha 0, beta 0: the bones chained from the fused roots, as forward kinematics
    out = model.fuse(bones, positions, torch.tensor([[[0.0, 0.0]]]))
    root = (bones[0, 0, layout.index(8)] + positions[0, 0, 8]) / 2
    chained = root + bones[0, 0, layout.index(9)] + bones[0, 0, i]
    torch.testing.assert_close(out[0, 0, child], chained)


@pytest.mark.parametrize(
    "roots, bones, message",
    [
        ([0], [[0, 1], [0, 1]], "must name each of the 3 joints once"),
        ([0], [[2, 1], [0, 2]], "parents before children"),
    ],
)
def test_a_bone_list_that_is_not_a_tree_is_refused(roots, bones, message):
    with pytest.raises(ValueError, match=message):
        TFAN(10, 5, 3, roots=roots, bones=bones, blocks=1, history_frames=10, chunk=5)


def _trained_parameters(model: TFAN, loss: torch.Tensor) -> set[str]:
    model.zero_grad(set_to_none=True)
    loss.backward()
    return {name.split(".")[0] for name, p in model.named_parameters() if p.grad is not None}


def test_the_streams_learn_first_then_the_gate_alone_on_the_fused_frames():
    model = zoo.create_model("tfan", benchmark="cmu50", blocks=2, streams_epochs=1)
    torch.manual_seed(1)
    history, future = 300 * torch.randn(2, 50, 25, 3), 300 * torch.randn(2, 25, 25, 3)
    model.start_epoch(0, frames=None)
    assert _trained_parameters(model, model.training_loss(history, future)) == {"position", "bone"}
    model.start_epoch(1, frames=None)
    loss = model.training_loss(history, future)
    # the gate's loss is the code's on the first 10 fused frames, which forward predicts first
    pred, target = model(history)[:, :10] / 1000, future[:, :10] / 1000
    moved = (pred.diff(dim=1) - target.diff(dim=1)).norm(dim=-1).mean()
    torch.testing.assert_close(loss, (pred - target).norm(dim=-1).mean() + moved)
    assert _trained_parameters(model, loss) == {"gate"}


def test_its_recipe_is_the_codes_stages_in_epochs_of_cmu50():
    from zoo.hub.weights import unshipped_models
    from zoo.models.recipe import learning_rate, training_recipe
    from zoo.models.registry import load_registry

    registry = load_registry()
    entry = registry.get("tfan")
    recipe = training_recipe(entry.train)
    assert recipe.epochs == 250 and recipe.batch_size == 64 and recipe.grad_clip is None
    streams = entry.hparams["streams_epochs"]
    assert streams == 240
    steps = 208  # an epoch: cmu50's 13,331 training windows in batches of 64 (registry.yaml)
    rate = [
        learning_rate(recipe.schedule, recipe.lr, step // steps, recipe.epochs, step)
        for step in (0, 39_999, 40_000, streams * steps - 1, streams * steps, 51_419, 51_420)
    ]
    assert rate == [3e-4, 3e-4, 1e-5, 1e-5, 3e-4, 3e-4, 1e-5]
    # the listing counts the recipe's epochs, however many a paused state has run
    assert re.search(r"\b\d+ of 250 epochs", unshipped_models(registry)["tfan"])
