"""MSR-GCN against its public code's facts, computed again here: the parameter count the code
prints on CMU (6,367,791), the coarser scales as means of the code's groups, the residual (a
zero readout predicts the last observed frame at every scale), the loss supervising every
scale, the range set from the training frames, and the registry recipe's learning rates."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from zoo.models.msrgcn import MSRGCN
from zoo.models.registry import load_registry

T_IN, T_OUT, POINTS = 10, 25, 25


def model(**overrides) -> MSRGCN:
    hparams = dict(load_registry().get("msrgcn").hparams, **overrides)
    return MSRGCN(T_IN, T_OUT, POINTS, **hparams)


def motion(batch: int, frames: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    base = 300 * torch.randn(batch, 1, POINTS, 3, generator=g)
    return base + 10 * torch.randn(batch, frames, POINTS, 3, generator=g).cumsum(dim=1)


def test_parameter_count_is_the_public_codes_on_cmu():
    # the code's MSRGCN(p_dropout, 0.2, final_out_noden=25, input_feature=35) prints 6.37M:
    # sum(p.numel() for p in m.parameters()) = 6,367,791
    assert sum(p.numel() for p in model().parameters()) == 6_367_791


def test_scales_are_means_of_the_codes_groups():
    m = model()
    groups = load_registry().get("msrgcn").hparams["groups"]
    x = motion(2, 5)
    scales = m.scales(x)
    assert [s.shape[2] for s in scales] == [25, 12, 7, 4]
    expected = x.numpy()
    for level, grouping in enumerate(groups):
        expected = np.stack([expected[:, :, g].mean(axis=2) for g in grouping], axis=2)
        assert np.allclose(scales[level + 1].numpy(), expected, atol=1e-4)


def test_a_zero_readout_predicts_the_last_observed_frame_at_every_scale():
    m = model().eval()
    for readout in m.readout:
        for p in readout.parameters():
            torch.nn.init.zeros_(p)
    m.low.fill_(-5000.0)
    m.high.fill_(7000.0)
    history = motion(3, T_IN)
    with torch.no_grad():
        frames = m.reconstruct(history)
    for level, (out, truth) in enumerate(zip(frames, m.scales(history))):
        last = truth[:, -1:].expand(-1, T_IN + T_OUT, -1, -1)
        assert torch.allclose(out[:, T_IN:], last[:, T_IN:], atol=0.05), level


def test_loss_supervises_every_scale_over_all_frames():
    m = model().eval()
    history, future = motion(2, T_IN), motion(2, T_OUT, seed=1)
    with torch.no_grad():
        loss = m.training_loss(history, future)
        outputs = m.reconstruct(history)
        targets = m.scales(torch.cat([history, future], dim=1))
        expected = sum(
            np.linalg.norm((o - t).numpy(), axis=-1).mean() for o, t in zip(outputs, targets)
        )
    assert len(outputs) == 4
    assert float(loss) == pytest.approx(expected, rel=1e-5)


def test_range_comes_from_the_training_frames_and_is_stored_with_the_weights():
    m = model()
    frames = motion(1, 40)[0]

    def batches():
        yield frames[:25], torch.ones(25)
        yield frames[25:], torch.ones(15)

    m.start_epoch(0, batches)
    root = np.sqrt(T_IN + T_OUT)
    positions = torch.cat([s.reshape(-1) for s in m.scales(frames[:, None])])
    assert float(m.low) == pytest.approx(min(0.0, root * float(positions.min())), rel=1e-6)
    assert float(m.high) == pytest.approx(max(0.0, root * float(positions.max())), rel=1e-6)
    assert int(m.range_frames) == 40 and {"low", "high", "range_frames"} <= set(m.state_dict())
    m.start_epoch(1, lambda: iter(()))  # set once: later epochs keep it
    assert int(m.range_frames) == 40
    with pytest.raises(ValueError, match="no training frames"):
        model().set_range(iter(()))


def test_bad_groups_and_shapes_are_refused_in_words():
    with pytest.raises(ValueError, match=r"groups\[1\]"):
        model(groups=[[[0, 1]], [[0, 5]]], widths=[8, 8, 8], head_blocks=[1, 1, 1])
    with pytest.raises(ValueError, match="widths and head_blocks"):
        model(widths=[64, 128])
    with pytest.raises(ValueError, match="history must have shape"):
        model()(torch.zeros(2, T_IN, 24, 3))


def test_recipe_decays_as_the_code_does():
    # the code: lr 2e-4, x 0.98 before epochs 2, 4, 6, ... (1-based)
    from zoo.models.recipe import learning_rate, training_recipe

    recipe = training_recipe(load_registry().get("msrgcn").train)
    rates = [learning_rate(recipe.schedule, recipe.lr, e, 50) for e in range(6)]
    expected = [2e-4 * 0.98 ** ((e + 1) // 2) for e in range(6)]
    assert rates == pytest.approx(expected)
    assert (recipe.batch_size, recipe.grad_clip) == (16, None)
    # to the released checkpoint's epoch, no patience, float32: what the shipped weights ran
    assert (recipe.epochs, recipe.patience, recipe.precision) == (58, None, "float32")
