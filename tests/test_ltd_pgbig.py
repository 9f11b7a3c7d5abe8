"""LTD and PGBIG against independent computations of their papers' equations.

Each model batches its products for speed (broadcast batched products, channel-last
permutations, a cheap dropout mask), so an axis mix-up would give a model that trains but is
not the paper's. Here the equations are written again in float64 with explicit einsums and loops
over the models' parameters, read by name:

- LTD: the DCT coefficients of the input padded with its last frame (against scipy's DCT-II),
  one graph convolution ``A (X W) + b``, the residual in DCT space (a zero readout predicts the
  last frame), the loss (mean joint distance over all frames) and the parameter counts (paper:
  2.55 M on Human3.6M's 66 nodes);
- PGBIG: the accumulated-average smoothing of the targets, one whole stage (encoder, copy,
  decoder) in eval mode, what each stage is given (the paper's Eq. 1: the observed frames and the
  previous stage's future), the loss and the parameter counts (paper: 1.74 M on Human3.6M,
  counted as the public code prints it);
- the dropout both use: the quantised keep probability and its scale, identity in eval mode.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.fft
import torch

from zoo.models.dct import dct_matrix
from zoo.models.dropout import Dropout
from zoo.models.ltd import LTD
from zoo.models.pgbig import PGBIG, Coder, smooth

T_IN, T_OUT, POINTS = 10, 25, 25  # the CMU setting


def motion(batch: int, frames: int, points: int = POINTS, seed: int = 0) -> torch.Tensor:
    """A smooth random motion in mm, float64."""
    g = torch.Generator().manual_seed(seed)
    steps = torch.randn(batch, frames, points, 3, generator=g, dtype=torch.float64)
    return 300 * torch.randn(batch, 1, points, 3, generator=g, dtype=torch.float64) + 10 * (
        steps.cumsum(dim=1)
    )


def exact(model):
    """The model in float64 with its DCT matrices built in float64 (``.double()`` alone would
    upcast their float32 rounding)."""
    model = model.double()
    dct = dct_matrix(model.dct.shape[1], torch.float64)[: model.dct_n]
    model.dct, model.idct = dct.contiguous(), dct.T.contiguous()
    return model


def padded(history: torch.Tensor, t_out: int) -> torch.Tensor:
    return torch.cat([history, history[:, -1:].expand(-1, t_out, -1, -1)], dim=1)


# ---- LTD ----------------------------------------------------------------------------------------


def test_ltd_input_is_the_dct_of_the_padded_history():
    model = exact(LTD(T_IN, T_OUT, POINTS))
    history = motion(3, T_IN)
    expected = scipy.fft.dct(padded(history, T_OUT).numpy(), type=2, norm="ortho", axis=1)
    # node 3p + c holds coordinate c of point p; features are the first dct_n coefficients
    expected = expected.reshape(3, T_IN + T_OUT, 3 * POINTS).transpose(0, 2, 1)[..., :35]
    np.testing.assert_allclose(model.coefficients(history).numpy(), expected, atol=1e-9)


def test_ltd_graph_convolution_is_a_times_xw_plus_b():
    model = exact(LTD(T_IN, T_OUT, POINTS))
    conv = model.blocks[3].first.conv
    x = torch.randn(2, 3 * POINTS, 256, dtype=torch.float64)
    a, w, b = conv.adjacency, conv.weight, conv.bias
    expected = torch.stack(
        [
            torch.stack(
                [
                    sum(a[n, m] * (x[s, m] @ w) for m in range(3 * POINTS)) + b
                    for n in range(3 * POINTS)
                ]
            )
            for s in range(2)
        ]
    )
    torch.testing.assert_close(conv(x), expected, rtol=1e-10, atol=1e-9)


def test_ltd_predicts_a_residual_in_dct_space():
    """With a zero readout the network adds nothing: the inverse DCT of all 35 coefficients of
    the padded input is the padded input, so the prediction is the last observed frame."""
    model = exact(LTD(T_IN, T_OUT, POINTS)).eval()
    for p in model.readout.parameters():
        torch.nn.init.zeros_(p)
    history = motion(2, T_IN)
    predicted = model(history)
    torch.testing.assert_close(predicted, history[:, -1:].expand_as(predicted))


def test_ltd_loss_is_the_mean_joint_distance_over_all_frames():
    model = exact(LTD(T_IN, T_OUT, POINTS)).eval()
    history, future = motion(2, T_IN), motion(2, T_OUT, seed=1)
    frames = model.reconstruct(history)
    target = torch.cat([history, future], dim=1)
    expected = ((frames - target) ** 2).sum(-1).sqrt().mean()
    torch.testing.assert_close(model.training_loss(history, future), expected)


def test_ltd_parameter_counts():
    count = lambda m: sum(p.numel() for p in m.parameters())
    assert count(LTD(T_IN, T_OUT, POINTS)) == 2_703_469  # CMU: 75 nodes
    assert count(LTD(10, 25, 22)) == 2_555_275  # H3.6M's 66 nodes: the 2.55 M PGBIG quotes


# ---- PGBIG --------------------------------------------------------------------------------------


def test_pgbig_targets_are_accumulated_averages():
    window = motion(2, T_IN + T_OUT)
    once = smooth(window, T_IN)
    expected = window.clone()
    for t in range(T_IN, T_IN + T_OUT):
        expected[:, t] = window[:, T_IN : t + 1].mean(dim=1)
    torch.testing.assert_close(once, expected)
    model = PGBIG(T_IN, T_OUT, POINTS)
    targets = model.stage_targets(window[:, :T_IN], window[:, T_IN:])
    torch.testing.assert_close(targets[3], window)  # the last stage learns the ground truth
    torch.testing.assert_close(targets[2], once)
    torch.testing.assert_close(targets[0], smooth(smooth(once, T_IN), T_IN))  # the smoothest


def plain_layer(layer, x):
    """``y[b,o,j,l] = sum_{c,k,m} A[j,k] W_c[c,o] W_L[m,l] x[b,c,k,m] + bias[l]``."""
    y = torch.einsum("bckm,ml->bckl", x, layer.coefficients)
    y = torch.einsum("jk,bckl->bcjl", layer.joints, y)
    return torch.einsum("co,bcjl->bojl", layer.channels, y) + layer.bias


def graph_layer(layer, x):
    """Plain layer, BatchNorm (eval: running statistics) over the flattened vector, tanh."""
    y = plain_layer(layer.layer, x)
    norm = layer.norm
    flat = y.reshape(y.shape[0], -1)
    flat = (flat - norm.running_mean) / torch.sqrt(norm.running_var + norm.eps)
    return torch.tanh(flat * norm.weight + norm.bias).reshape(y.shape)


def coder(module, x):
    y = graph_layer(module.first, x)
    for block in module.blocks:
        y = graph_layer(block.second, graph_layer(block.first, y)) + y
    skip = torch.einsum("oc,bcjl->bojl", module.skip.weight[:, :, 0, 0], x)
    return plain_layer(module.last, y) + skip + module.skip.bias[:, None, None]


def test_pgbig_stage_is_encoder_copy_decoder():
    model = exact(PGBIG(T_IN, T_OUT, POINTS)).eval()
    stage = model.stages[1]
    g = torch.Generator().manual_seed(3)
    for module in stage.modules():  # running statistics other than 0 and 1
        if isinstance(module, torch.nn.BatchNorm1d):
            module.running_mean.normal_(generator=g).mul_(0.1)
            module.running_var.uniform_(0.5, 1.5, generator=g)
    x = torch.randn(2, 3, POINTS, 35, generator=g, dtype=torch.float64)
    latent = coder(stage.encoder, x)
    expected = coder(stage.decoder, torch.cat([latent, latent], dim=-1))[..., :35]
    torch.testing.assert_close(stage(x), expected, rtol=1e-10, atol=1e-10)


def test_pgbig_coder_on_copies_and_kept_coefficients_is_the_coder_on_the_whole():
    """A coder given ``x`` and ``copies`` computes, of its output on ``x`` repeated along the
    coefficient axis, the first ``keep`` coefficients, whichever axis its layers shrink."""
    g = torch.Generator().manual_seed(5)
    for in_channels, hidden, out_channels in ((3, 5, 4), (4, 5, 3), (6, 2, 3)):
        module = exact_coder(POINTS, 14, in_channels, hidden, out_channels, g)
        x = torch.randn(2, in_channels, POINTS, 7, generator=g, dtype=torch.float64)
        whole = coder(module, torch.cat([x, x], dim=-1))
        for keep in (None, 5, 7, 11, 14):
            expected = whole if keep is None else whole[..., :keep]
            torch.testing.assert_close(
                module(x, copies=2, keep=keep), expected, rtol=1e-10, atol=1e-10
            )
        torch.testing.assert_close(module(torch.cat([x, x], dim=-1)), whole, rtol=1e-10, atol=1e-10)
    with pytest.raises(ValueError, match="14 coefficients given 2 x 2"):
        module.last(torch.zeros(1, hidden, POINTS, 2), copies=2, keep=7)


def exact_coder(joints, length, in_channels, hidden, out_channels, g):
    module = Coder(joints, length, in_channels, hidden, out_channels, 1, 0.3).double().eval()
    for norm in module.modules():
        if isinstance(norm, torch.nn.BatchNorm1d):
            norm.running_mean.normal_(generator=g).mul_(0.1)
            norm.running_var.uniform_(0.5, 1.5, generator=g)
    return module


def test_pgbig_stages_get_the_observed_frames_and_the_previous_future():
    history = motion(2, T_IN)
    for stage_input in ("observed", "previous"):
        model = exact(PGBIG(T_IN, T_OUT, POINTS, stage_input=stage_input)).eval()
        seen = []
        for stage in model.stages:
            stage.register_forward_pre_hook(lambda module, args, seen=seen: seen.append(args[0]))
        outputs = model.stage_outputs(history)
        assert len(seen) == 4 and len(outputs) == 4
        torch.testing.assert_close(model.to_frames(seen[0]), padded(history, T_OUT))
        for i in (1, 2, 3):
            given = model.to_frames(seen[i])
            if stage_input == "observed":  # paper, Eq. 1
                torch.testing.assert_close(given[:, :T_IN], history)
                torch.testing.assert_close(given[:, T_IN:], outputs[i - 1][:, T_IN:])
            else:  # public code: the previous stage's whole output
                torch.testing.assert_close(given, outputs[i - 1])
        assert not torch.allclose(model.to_frames(seen[1])[:, :T_IN], outputs[0][:, :T_IN]) or (
            stage_input == "previous"
        )


def test_pgbig_loss_averages_the_stages_against_their_targets():
    model = exact(PGBIG(T_IN, T_OUT, POINTS)).eval()
    history, future = motion(2, T_IN), motion(2, T_OUT, seed=1)
    outputs = model.stage_outputs(history)
    targets = model.stage_targets(history, future)
    expected = sum(((o - t) ** 2).sum(-1).sqrt().mean() for o, t in zip(outputs, targets)) / 4
    torch.testing.assert_close(model.training_loss(history, future), expected)
    torch.testing.assert_close(model(history), outputs[-1][:, T_IN:])


def test_pgbig_parameter_counts():
    count = lambda m: sum(p.numel() for p in m.parameters())
    assert count(PGBIG(T_IN, T_OUT, POINTS)) == 1_629_476  # CMU: 25 joints
    # H3.6M's 22 joints: 1.449 M, plus the two BatchNorm layers per stage that the public code
    # builds and never uses (16 x 22 x 35 and 16 x 22 x 70 features, weight and bias): 1.74 M
    unused = 4 * 2 * (16 * 22 * 35 + 16 * 22 * 70)
    assert count(PGBIG(10, 25, 22)) + unused == 1_744_796


def test_pgbig_rejects_an_unknown_stage_input():
    with pytest.raises(ValueError, match="stage_input must be one of observed, previous"):
        PGBIG(T_IN, T_OUT, POINTS, stage_input="paper")


# ---- dropout ------------------------------------------------------------------------------------


@pytest.mark.parametrize("p", [0.3, 0.5])
def test_dropout_keeps_with_the_quantised_probability_and_rescales(p):
    torch.manual_seed(0)
    layer = Dropout(p)
    x = torch.ones(400, 1000)
    y = layer(x)
    kept = y != 0
    keep = 1 - round(p * 65536) / 65536
    assert abs(kept.double().mean().item() - keep) < 4 * (keep * (1 - keep) / x.numel()) ** 0.5
    assert torch.allclose(y[kept], torch.tensor(1 / keep))
    # every 16-bit lane is used: the drop rate is the same in all four lanes of a word
    lanes = kept.flatten()[: 4 * (x.numel() // 4)].view(-1, 4).double().mean(0)
    assert (lanes - keep).abs().max() < 0.01
    assert torch.equal(layer.eval()(x), x)
    with pytest.raises(ValueError, match="p must be a probability"):
        Dropout(1.0)
    with pytest.raises(ValueError, match="rounds to 1 at the mask's resolution"):
        Dropout(0.999995)


# ---- recipes ------------------------------------------------------------------------------------


def test_recipes_decay_the_rate_as_the_public_codes_do():
    """LTD's code multiplies the rate by 0.96 at the start of every second epoch from the
    second on; PGBIG's by 0.1^(1/50) at the start of every epoch, the first included."""
    from zoo.models.recipe import learning_rate, training_recipe
    from zoo.models.registry import load_registry

    registry = load_registry()
    ltd = training_recipe(registry.get("ltd").train)
    rates = [learning_rate(ltd.schedule, ltd.lr, e, 50) for e in range(4)]
    np.testing.assert_allclose(rates, [5e-4, 5e-4 * 0.96, 5e-4 * 0.96, 5e-4 * 0.96**2])
    pgbig = training_recipe(registry.get("pgbig").train)
    rates = [learning_rate(pgbig.schedule, pgbig.lr, e, 50) for e in (0, 49)]
    np.testing.assert_allclose(rates, [5e-3 * 0.1 ** (1 / 50), 5e-3 * 0.1])
    assert (ltd.batch_size, ltd.epochs, pgbig.batch_size, pgbig.epochs) == (
        16,
        50,
        16,
        50,
    )
