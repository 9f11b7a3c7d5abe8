"""A tiny trainable model for engine tests, registered from outside zoo/ like a user's own."""

import torch
from torch import nn

REGISTRY = """\
models:
  tiny:
    class: tiny_models.py:TinyTemporal
    representation: joints
    trainable: true
    hparams: {hidden: 16, poison: false}
    reference: test model
    train: {lr: 0.001, batch_size: 8, epochs: 2, grad_clip: 1.0,
            schedule: {type: step, every_epochs: 1, gamma: 0.5}, augment: [time_reversal]}
  tiny_completion:
    class: tiny_models.py:TinyCompletion
    representation: joints
    trainable: true
    task: completion
    hparams: {}
    reference: test model
    train: {lr: 0.01, batch_size: 8, epochs: 1}
"""


class TinyCompletion(nn.Module):
    """In-betweening with one learned weight per output frame on the final frame."""

    def __init__(self, input_frames, output_frames, num_points):
        super().__init__()
        self.weight = nn.Parameter(torch.zeros(output_frames))

    def forward(self, history, final_frame):
        w = self.weight.view(1, -1, 1, 1)
        return history[:, -1:] * (1 - w) + final_frame[:, None] * w


class TinyTemporal(nn.Module):
    """Residual temporal MLP with dropout (so resuming must restore the RNG too); ``poison``:
    non-finite predictions while training only (a loss that turns NaN mid-run)."""

    def __init__(self, input_frames, output_frames, num_points, hidden=16, poison=False):
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(input_frames, hidden),
            nn.Dropout(0.2),
            nn.ReLU(),
            nn.Linear(hidden, output_frames),
        )
        self.poison = poison

    def forward(self, history):
        last = history[:, -1:]
        x = (history - last).permute(0, 2, 3, 1)
        # Contiguous before the residual: the permuted layout would make the loss's norm over
        # the coordinates a strided reduction.
        y = self.net(x).permute(0, 3, 1, 2).contiguous() + last
        return y * float("nan") if self.poison and self.training else y


MESH_REGISTRY = """\
models:
  tiny_spectral:
    class: tiny_models.py:TinySpectral
    representation: mesh
    trainable: true
    context: [basis]
    hparams: {}
    reference: test model
    train: {lr: 0.01, batch_size: 4, epochs: 2, val_fraction: 0.25}
  tiny_spectral_still:
    class: tiny_models.py:TinySpectralStill
    representation: mesh
    weights_of: tiny_spectral
    context: [basis]
    hparams: {}
    reference: test model
"""


class TinySpectral(nn.Module):
    """Predicts in the spectral domain: a learned per-frequency extrapolation of the last frame."""

    def __init__(self, input_frames, output_frames, num_points, basis):
        super().__init__()
        if basis.vectors.shape[0] != num_points:
            raise ValueError("basis does not fit the mesh")
        self.basis, self.output_frames = basis, output_frames
        self.gain = nn.Parameter(torch.zeros(basis.k, 1))

    def forward(self, history):
        coeffs = self.basis.project(history)
        last, velocity = coeffs[:, -1], coeffs[:, -1] - coeffs[:, -2]
        steps = torch.arange(1, self.output_frames + 1, dtype=history.dtype).view(1, -1, 1, 1)
        return self.basis.reconstruct(last[:, None] + steps * self.gain * velocity[:, None])


class TinySpectralStill(TinySpectral):
    """TinySpectral's weights, inference changed: half the learned extrapolation."""

    def forward(self, history):
        return 0.5 * (super().forward(history) + history[:, -1:])


def weights_record(model: str = "tiny", label: str | None = None, **fields):
    """A shipped weights record of ``model`` on cmu, with ``fields`` (training, history, ...)
    set: what the readers of records are tested on without exporting a file."""
    from zoo.hub.records import WeightsRecord

    label = label or model
    return WeightsRecord(
        model=model,
        hparams=fields.pop("hparams", {}),
        protocol={"benchmark": "cmu"},
        label=label,
        benchmark="cmu",
        file=f"{label}.safetensors",
        sha256="0" * 64,
        dtype="float16",
        parameters=12,
        **fields,
    )
