"""SpecTrHuMS with a residual transformer (a zoo change, not the paper's): the transformer
predicts each latent of the window as a change from its input there.

The paper's transformer outputs the latents themselves. Its input window is the observed latents
followed by the last observed one repeated, so with ``out = input + f(input)`` and ``f``'s last
layer initialised to zero the untrained model reproduces the observed latents exactly and
repeats the last one (in latent space: its frames are the autoencoder's rendering of the last
observed frame); training moves it away from there only as far as the data ask. The
autoencoder, losses and inference are SpecTrHuMS's own.
"""

from __future__ import annotations

from torch import Tensor, nn

from zoo.models.spectrhums import LatentTransformer, SpecTrHuMS
from zoo.models.spectrhums_anchored import AnchoredSpecTrHuMS


class ResidualTransformer(nn.Module):
    """``x + inner(x)`` for a :class:`zoo.models.spectrhums.LatentTransformer` ``inner``, whose
    output layer starts at zero."""

    def __init__(self, inner: LatentTransformer) -> None:
        super().__init__()
        self.inner = inner
        nn.init.zeros_(inner.out.weight)
        nn.init.zeros_(inner.out.bias)

    def forward(self, x: Tensor) -> Tensor:
        return x + self.inner(x)


class ResidualSpecTrHuMS(SpecTrHuMS):
    """:class:`zoo.models.spectrhums.SpecTrHuMS` whose transformer is a
    :class:`ResidualTransformer`; built with the same random numbers as the paper's model, so
    at one seed the two differ only in the transformer's output layer."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.transformer = ResidualTransformer(self.transformer)


class AnchoredResidualSpecTrHuMS(AnchoredSpecTrHuMS, ResidualSpecTrHuMS):
    """The residual model's weights with anchored inference
    (:class:`zoo.models.spectrhums_anchored.AnchoredSpecTrHuMS`)."""
