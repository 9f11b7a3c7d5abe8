"""AuxFormer (zoo.models.auxformer): its size, the frames it predicts and the ones it draws
between them, what its prediction may not read, and its auxiliary draws. Its equality with the
public code is measured by benchmarks/speed/public_auxformer.py (docs/models/auxformer.md)."""

from __future__ import annotations

import pytest
import torch

import zoo
from zoo.models.auxformer import AuxFormer, Corruption


def _model() -> AuxFormer:
    torch.manual_seed(0)
    return zoo.create_model("auxformer", benchmark="cmu").eval()


def _history(batch: int = 2) -> torch.Tensor:
    torch.manual_seed(1)
    return 300 * torch.randn(batch, 1, 25, 3) + 20 * torch.randn(batch, 10, 25, 3).cumsum(1)


def test_size_as_the_public_long_cmu_model():
    model = _model()
    # the public AuxFormer of cfg/cmu_long.yml (benchmarks/speed/public_auxformer.py)
    assert sum(p.numel() for p in model.parameters()) == 1_458_613
    assert model.predicted == [2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 25]
    assert model(_history()).shape == (2, 25, 25, 3)


def test_predicted_frames_are_the_models_and_the_others_lie_on_straight_lines():
    model = _model()
    history = _history()
    with torch.no_grad():
        out = model(history)
        trajectory = model._trajectory(history, None)
        predicted = model.predict_units(trajectory).permute(0, 2, 1, 3) * 100.0
    frames = [f - 1 for f in model.predicted]
    torch.testing.assert_close(out[:, frames], predicted)
    # frame 1 halfway from the last observed frame to frame 2; frame 3 between 2 and 4
    torch.testing.assert_close(out[:, 0], (history[:, -1] + out[:, 1]) / 2)
    torch.testing.assert_close(out[:, 2], (out[:, 1] + out[:, 3]) / 2)
    torch.testing.assert_close(out[:, 22], (out[:, 21] + out[:, 23]) / 2)


def test_prediction_reads_no_future_value():
    model = _model()
    history = _history()
    future = 300 * torch.randn(2, 25, 25, 3)
    with torch.no_grad():
        blank = model.predict_units(model._trajectory(history, None))
        told = model.predict_units(model._trajectory(history, future))
    torch.testing.assert_close(blank, told)


def _encoded_as_the_code(model: AuxFormer, trajectory, mask) -> list[torch.Tensor]:
    """The code's mask_forward written again: the encoder on all T frames under masks ``(B, N,
    T)``, its outputs kept where visible."""
    b, n, t, _ = trajectory.shape
    velocity = torch.zeros_like(trajectory)
    velocity[:, :, 1:] = trajectory[:, :, 1:] - trajectory[:, :, :-1]
    acceleration = torch.zeros_like(velocity)
    acceleration[:, :, 1:] = velocity[:, :, 1:] - velocity[:, :, :-1]
    visible = mask[..., None]
    tokens = model.patch_embed(torch.cat([trajectory, velocity, acceleration], dim=-1))
    tokens = (tokens * visible + model.pos_embed + model.agent_embed) * visible
    per_frame = mask.permute(0, 2, 1).reshape(b * t, n)
    per_joint = mask.reshape(b * n, t)
    mask_s = per_frame[:, :, None] * per_frame[:, None, :]
    mask_t = per_joint[:, :, None] * per_joint[:, None, :]
    queries = model.mask_embed + model.decoder_pos_embed.weight[None, None]
    queries = (queries + model.decoder_agent_embed.weight[None, :, None]) * (1 - visible)
    out = []
    for layer, (encoder, decoder) in enumerate(zip(model.encoder, model.decoder)):
        if layer == 0:
            decoded = encoder(tokens, mask_s, mask_t) * visible + queries
        else:
            encoded = encoder(decoded * visible, mask_s, mask_t)
            decoded = encoded * visible + decoded * (1 - visible)
        decoded = decoder(decoded)
        out.append(decoded)
    return out


@pytest.mark.parametrize("hiding", [False, True], ids=["observed", "masking draw"])
def test_the_encoder_reading_the_observed_frames_alone_is_the_codes_masked_encoder(hiding):
    """The predicted frames are hidden from every attention of the code's encoder and its
    outputs there dropped: reading the observed frames alone gives every block's tokens, and
    every gradient, of the code's way, for the prediction's mask and for a masking draw."""
    model = _model()
    trajectory = model._trajectory(_history(), 300 * torch.randn(2, 25, 25, 3))
    mask = model.observed_mask(trajectory)
    visible = None
    if hiding:
        torch.manual_seed(3)
        visible = model.draw_corruption(trajectory).visible
        mask = torch.cat([visible, mask[:, :, model.input_frames :]], dim=2)
    results = []
    for encode in (lambda: _encoded_as_the_code(model, trajectory, mask),
                   lambda: model.encode(trajectory, visible)):  # fmt: skip
        model.zero_grad()
        blocks = encode()
        sum(b.square().mean() for b in blocks).backward()
        grads = {n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None}
        results.append(([b.detach() for b in blocks], grads))
    (code_blocks, code_grads), (blocks, grads) = results
    for theirs, ours in zip(code_blocks, blocks, strict=True):
        torch.testing.assert_close(ours, theirs, rtol=1e-5, atol=1e-5)
    assert grads.keys() == code_grads.keys()
    for name, ours in grads.items():
        torch.testing.assert_close(ours, code_grads[name], rtol=1e-4, atol=1e-6, msg=name)


def test_auxiliary_draws_hide_the_code_share_of_observed_tokens():
    model = _model()
    trajectory = model._trajectory(_history(4), 300 * torch.randn(4, 25, 25, 3))
    torch.manual_seed(2)
    corruption = model.draw_corruption(trajectory)
    hidden = int(25 * 10 * 0.4)
    assert corruption.visible.shape == (4, 25, 10)
    assert (corruption.visible.sum(dim=(1, 2)) == 25 * 10 - hidden).all()
    noised = (corruption.noise != 0).any(dim=-1).float().mean().item()
    assert 0.3 < noised < 0.5  # noise_ratio 0.4 of the tokens


def test_every_parameter_learns_from_the_three_tasks():
    model = _model().train()
    history = _history()
    model.training_loss(history, 300 * torch.randn(2, 25, 25, 3)).backward()
    silent = [n for n, p in model.named_parameters() if p.grad is None or not p.grad.any()]
    assert silent == []


def test_the_noise_reaches_the_denoising_term():
    model = _model()
    trajectory = model._trajectory(_history(), 300 * torch.randn(2, 25, 25, 3))
    clean = Corruption(torch.ones(2, 25, 10), torch.zeros_like(trajectory))
    noisy = Corruption(torch.ones(2, 25, 10), torch.ones_like(trajectory))
    with torch.no_grad():
        assert model.corrupted_loss(trajectory, clean) != model.corrupted_loss(trajectory, noisy)


@pytest.mark.parametrize(
    "change, message",
    [
        ({"noise_std": [1.0, 0.1]}, "noise_std must be \\[low, high\\]"),
        ({"mask_ratio": 1.5}, "mask_ratio must be a number in \\[0, 1\\]"),
        ({"frame_stride": 0}, "frame_stride must be an integer >= 1"),
    ],
)
def test_bad_hyper_parameters_are_refused_by_name(change, message):
    with pytest.raises(ValueError, match=message):
        AuxFormer(10, 25, 25, **change)
