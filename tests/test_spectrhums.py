"""SpecTrHuMS: statistics, masking, phases, the three tasks, its config, errors and checkpoints.

Small configurations on a small mesh: the basis is the low-frequency eigenvectors of the graph
Laplacian of a 6 x 5 grid, computed here (the tests do not depend on zoo.data.spectral).
"""

import hashlib
import io

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import nn

from zoo.data.spectral import SpectralBasis
from zoo.models.latent_transformer import EncoderLayer
from zoo.models.recipe import learning_rate, training_recipe
from zoo.models.registry import load_registry
from zoo.models.spectral_autoencoder import SpectralAutoencoder
from zoo.models.spectrhums import SpecTrHuMS, SpecTrHuMSConfig, SpecTrHuMSError, Welford

T_IN, T_OUT = 6, 4
W = T_IN + T_OUT
SMALL = dict(latent=16, channels=(4, 8), pooling=(6, 3), d_model=16, layers=2, heads=2, ff=32)


class GridBasis(SpectralBasis):
    """The ``k`` smoothest eigenvectors of the combinatorial Laplacian of a rows x cols grid."""

    def __init__(self, rows=6, cols=5, k=12):
        n = rows * cols
        a = np.zeros((n, n))
        for r in range(rows):
            for c in range(cols):
                i = r * cols + c
                if c + 1 < cols:
                    a[i, i + 1] = a[i + 1, i] = 1
                if r + 1 < rows:
                    a[i, i + cols] = a[i + cols, i] = 1
        values, vecs = np.linalg.eigh(np.diag(a.sum(1)) - a)
        super().__init__(
            hashlib.sha256(a.tobytes()).hexdigest(), values[:k], vecs[:, :k], f"grid{rows}x{cols}"
        )


BASIS = GridBasis()
V = BASIS.vectors.shape[0]


def make(task="prediction", basis=BASIS, seed=0, **kw):
    torch.manual_seed(seed)
    return SpecTrHuMS(T_IN, T_OUT, V, basis, task=task, **{**SMALL, **kw})


def motion(batch, frames=W, seed=1):
    """Smooth random motions of the grid, in mm."""
    g = torch.Generator().manual_seed(seed)
    rest = torch.randn(batch, 1, V, 3, generator=g) * 300
    speed = torch.randn(batch, 1, V, 3, generator=g) * 20
    t = torch.arange(frames, dtype=torch.float32)[None, :, None, None]
    return rest + speed * torch.sin(0.3 * t + torch.randn(batch, 1, V, 1, generator=g))


WINDOW_BATCHES = [motion(5, seed=2), motion(3, seed=3), motion(4, seed=4)]


def frames():
    """The frames of WINDOW_BATCHES as the engine gives them: each once, with its count."""
    for batch in WINDOW_BATCHES:
        flat = batch.flatten(0, 1)
        yield flat, torch.ones(len(flat), dtype=torch.int64)


def trained_stats(model, epoch=2):
    model.start_epoch(0, frames)
    if epoch:
        model.start_epoch(epoch, frames)
    return model


def all_coefficients():
    frames = torch.cat(WINDOW_BATCHES).flatten(0, 1).double()
    return BASIS.project(frames)  # (N, k, 3)


# ---- statistics --------------------------------------------------------------------------------


def test_welford_equals_numpy_over_uneven_batches():
    rng = np.random.default_rng(0)
    rows = rng.normal(5.0, 3.0, size=(101, 4, 3))
    w = Welford((4, 3))
    for part in np.split(rows, [1, 8, 50, 51]):
        w.update(torch.from_numpy(part))
    mean, std = w.finalize("test")
    assert w.count == 101
    np.testing.assert_allclose(mean.numpy(), rows.mean(0), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(std.numpy(), rows.std(0, ddof=1), rtol=1e-12)


def test_welford_counts_weight_rows_as_repeats():
    rng = np.random.default_rng(1)
    rows = rng.normal(-2.0, 4.0, size=(40, 5))
    counts = rng.integers(0, 6, size=40)
    w = Welford((5,))
    for part in np.split(np.arange(40), [3, 17, 18]):
        w.update(torch.from_numpy(rows[part]), torch.from_numpy(counts[part]))
    mean, std = w.finalize("test")
    repeated = np.repeat(rows, counts, axis=0)
    assert w.count == len(repeated) == counts.sum()
    np.testing.assert_allclose(mean.numpy(), repeated.mean(0), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(std.numpy(), repeated.std(0, ddof=1), rtol=1e-12)
    with pytest.raises(SpecTrHuMSError, match="3 counts for 2 rows"):
        w.update(torch.zeros(2, 5), torch.ones(3, dtype=torch.int64))


def test_start_epoch_on_counted_frames_equals_the_repeated_frames():
    """The engine gives each distinct frame once with the number of windows holding it."""
    distinct = motion(1, frames=20, seed=7)[0]
    counts = torch.arange(20) % 4  # some frames in no window at all
    counted, repeated = make(), make()
    counted.start_epoch(2, lambda: iter([(distinct, counts)]))
    repeated.start_epoch(
        2,
        lambda: iter(
            [
                (
                    distinct.repeat_interleave(counts, 0),
                    torch.ones(int(counts.sum()), dtype=torch.int64),
                )
            ]
        ),
    )
    assert int(counted.coeff_frames) == int(repeated.coeff_frames) == int(counts.sum())
    for name in ("coeff_mean", "coeff_std", "latent_mean", "latent_std"):
        torch.testing.assert_close(
            getattr(counted, name), getattr(repeated, name), rtol=1e-5, atol=1e-5
        )


def test_start_epoch_statistics_equal_numpy_over_the_training_frames():
    model = make()
    model.start_epoch(0, frames)
    coeffs = all_coefficients().numpy()
    assert int(model.coeff_frames) == len(coeffs) == 12 * W
    np.testing.assert_allclose(model.coeff_mean.numpy(), coeffs.mean(0), rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(model.coeff_std.numpy(), coeffs.std(0, ddof=1), rtol=1e-5)
    assert model.phase == "autoencoder" and int(model.latent_frames) == 0

    model.start_epoch(2, frames)  # the transformer trains from epoch 2 on: latent statistics
    assert model.phase == "joint"
    with torch.no_grad():
        latents = model.encode(all_coefficients().float()).double().numpy()
    assert int(model.latent_frames) == len(latents)
    np.testing.assert_allclose(model.latent_mean.numpy(), latents.mean(0), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(model.latent_std.numpy(), latents.std(0, ddof=1), rtol=1e-5)


def test_latent_statistics_follow_the_encoder_every_epoch():
    model = trained_stats(make())
    before = model.latent_mean.clone()
    with torch.no_grad():
        model.autoencoder.to_latent.bias += 1.0
    model.start_epoch(3, frames)
    torch.testing.assert_close(model.latent_mean, before + 1.0)
    coeff_mean = model.coeff_mean.clone()
    model.start_epoch(4, frames)  # coefficient statistics are kept after the first epoch
    assert torch.equal(model.coeff_mean, coeff_mean)


def test_coefficient_standardisation_round_trip():
    model = trained_stats(make(), epoch=0)
    coeffs = all_coefficients().float()
    std = model.standardise_coefficients(coeffs)
    torch.testing.assert_close(model.destandardise_coefficients(std), coeffs, rtol=1e-5, atol=1e-3)
    torch.testing.assert_close(std.mean(0), torch.zeros(BASIS.k, 3), rtol=0, atol=1e-4)
    torch.testing.assert_close(std.std(0), torch.ones(BASIS.k, 3), rtol=1e-4, atol=1e-4)


# ---- the basis -----------------------------------------------------------------------------------


def test_projection_and_reconstruction_are_single_matrix_products():
    model = make()
    vertices = motion(3)
    coeffs = model.project(vertices)
    torch.testing.assert_close(
        coeffs.double(), BASIS.project(vertices.double()), rtol=1e-5, atol=1e-3
    )
    torch.testing.assert_close(
        model.reconstruct(coeffs).double(), BASIS.reconstruct(coeffs.double()), rtol=1e-5, atol=1e-3
    )
    torch.testing.assert_close(
        model._project_frames(vertices[:, :T_IN], vertices[:, T_IN:]), coeffs
    )
    for fn, args in (
        (model.project, (vertices,)),
        (model.reconstruct, (coeffs,)),
        (model._project_frames, (vertices[:, :T_IN], vertices[:, T_IN:])),
    ):
        with torch.profiler.profile() as prof:
            fn(*args)
        names = [e.name for e in prof.events()]
        assert names.count("aten::mm") == 1, names
        assert "aten::bmm" not in names


def test_bfloat16_autocast_keeps_the_basis_products_and_decoder_output_in_float32():
    model = trained_stats(make()).eval()  # no dropout: the two passes differ by precision only
    vertices = motion(2)
    with torch.no_grad():
        coeffs, rebuilt = model.project(vertices), model.reconstruct(model.project(vertices))
        plain = model.predict_coefficients(coeffs[:, :T_IN])
        with torch.autocast("cpu", dtype=torch.bfloat16):
            # millimetre coordinates: bfloat16 would round them by up to 2**-8 of their size
            assert model.project(vertices).dtype == torch.float32
            torch.testing.assert_close(model.project(vertices), coeffs)
            torch.testing.assert_close(model.reconstruct(coeffs), rebuilt)
            mixed = model.predict_coefficients(coeffs[:, :T_IN])
            terms = model.coefficient_loss_terms(model.project(vertices))
    assert mixed.dtype == torch.float32  # the decoder's last layer and de-standardisation
    assert not torch.equal(mixed, plain)  # the layers in between did run in bfloat16
    torch.testing.assert_close(mixed, plain, rtol=0.05, atol=0.05 * float(plain.abs().max()))
    assert all(torch.isfinite(t) and t.dtype == torch.float32 for t in terms.values())


# ---- the architecture ----------------------------------------------------------------------------


def test_autoencoder_equals_its_layers_applied_one_after_the_other():
    torch.manual_seed(0)
    ae = SpectralAutoencoder(40, [4, 8], [16, 8], 3, 24).double()
    for p in ae.parameters():
        nn.init.normal_(p, std=0.3)
    x, z = torch.randn(7, 40, 3, dtype=torch.float64), torch.randn(7, 24, dtype=torch.float64)
    h = x.transpose(1, 2)
    for conv, pool in zip(ae.encoder_convs, ae.encoder_pools):
        h = F.elu(pool(conv(h)))
    torch.testing.assert_close(ae.encode(x), ae.to_latent(h.flatten(1)))
    h = ae.from_latent(z).view(7, 8, 8)
    for pool, conv in zip(ae.decoder_pools, ae.decoder_convs):
        h = F.elu(conv(pool(h)))
    torch.testing.assert_close(ae.decode(z), ae.to_coordinates(h).transpose(1, 2))
    assert [c.in_channels for c in ae.decoder_convs] == [8, 4]
    assert ae.to_coordinates.in_channels == 4 and ae.to_coordinates.out_channels == 3


def test_encoder_layer_equals_torch_post_norm_layer():
    torch.manual_seed(0)
    mine = EncoderLayer(16, 4, 32, 0.0).double()
    ref = nn.TransformerEncoderLayer(
        16, 4, 32, 0.0, activation="gelu", batch_first=True, norm_first=False
    ).double()
    with torch.no_grad():
        ref.self_attn.in_proj_weight.copy_(mine.qkv.weight)
        ref.self_attn.in_proj_bias.copy_(mine.qkv.bias)
        for a, b in (
            (ref.self_attn.out_proj, mine.attn_out),
            (ref.linear1, mine.ff1),
            (ref.linear2, mine.ff2),
            (ref.norm1, mine.norm1),
            (ref.norm2, mine.norm2),
        ):
            a.weight.copy_(b.weight)
            a.bias.copy_(b.bias)
    x = torch.randn(3, 9, 16, dtype=torch.float64)
    torch.testing.assert_close(mine(x), ref(x))


def test_published_configuration_has_six_million_parameters():
    q, _ = np.linalg.qr(np.random.default_rng(0).standard_normal((600, 512)))
    basis = type("B", (), {"vectors": q, "hash": "random600x512", "k": 512})()
    model = load_registry().create_model(
        "spectrhums", input_frames=50, output_frames=25, num_points=600, basis=basis
    )
    assert sum(p.numel() for p in model.parameters()) == 6_006_755  # public code: 6.0 M
    assert sum(p.numel() for p in model.transformer.parameters()) == 4_870_144


# ---- the window the transformer sees --------------------------------------------------------


def test_prediction_output_ignores_the_future_frames_of_the_window():
    model = make().eval()
    z = torch.randn(2, W, SMALL["latent"])
    masked = model.masked_window(z)
    assert torch.equal(masked[:, :T_IN], z[:, :T_IN])
    assert torch.equal(masked[:, T_IN:], z[:, T_IN - 1 : T_IN].expand(-1, T_OUT, -1))
    assert model.known_frames.tolist() == [True] * T_IN + [False] * T_OUT
    changed = z.clone()
    changed[:, T_IN:] += torch.randn(2, T_OUT, SMALL["latent"])
    with torch.no_grad():
        out = model.transform_window(z)
        assert torch.equal(model.transform_window(changed), out)
        observed = z.clone()
        observed[:, T_IN - 2] += 1.0  # an observed frame does change it
        assert not torch.allclose(model.transform_window(observed), out)


def test_completion_output_follows_the_final_frame_not_the_frames_in_between():
    model = make("completion").eval()
    z = torch.randn(2, W, SMALL["latent"])
    masked = model.masked_window(z)
    alpha = torch.arange(1, T_OUT + 1) / T_OUT
    expected = z[:, T_IN - 1 : T_IN] + alpha[:, None] * (z[:, -1:] - z[:, T_IN - 1 : T_IN])
    torch.testing.assert_close(masked[:, T_IN:], expected)
    assert torch.equal(masked[:, -1], z[:, -1])
    assert model.known_frames.tolist() == [True] * T_IN + [False] * (T_OUT - 1) + [True]
    between, final = z.clone(), z.clone()
    between[:, T_IN : W - 1] += 5.0
    final[:, -1] += 1.0
    with torch.no_grad():
        out = model.transform_window(z)
        assert torch.equal(model.transform_window(between), out)
        assert not torch.allclose(model.transform_window(final), out)

    trained_stats(model)
    history, future = motion(2)[:, :T_IN], motion(2)[:, T_IN:]
    with torch.no_grad():
        out = model(history, final_frame=future[:, -1])
        assert out.shape == (2, T_OUT, V, 3)
        assert not torch.allclose(model(history, final_frame=future[:, -1] + 50.0), out)
        assert torch.equal(model(history, final_frame=future[:, -1:]), out)


@pytest.mark.parametrize("task", ["prediction", "completion"])
def test_training_feeds_the_transformer_the_masked_window(task):
    """In training the transformer's input is built from the known frames only: for completion
    the final frame is the last frame of ``future``."""
    model = trained_stats(make(task))
    seen = []
    model.transformer.register_forward_hook(lambda mod, args, out: seen.append(args[0].detach()))
    window = motion(3)
    model.loss_terms(window[:, :T_IN], window[:, T_IN:])
    with torch.no_grad():
        target = model.standardise_latents(model.encode(model.project(window)))
    torch.testing.assert_close(seen[0], model.masked_window(target))
    changed = window.clone()
    changed[:, T_IN : W - 1] += 100.0  # frames the model must not see
    model.loss_terms(changed[:, :T_IN], changed[:, T_IN:])
    torch.testing.assert_close(seen[1], seen[0])


# ---- phases and gradients ------------------------------------------------------------------------


def _grads(loss, params):
    return torch.autograd.grad(loss, list(params), retain_graph=True, allow_unused=True)


def test_autoencoder_trains_alone_for_the_first_two_epochs():
    model = make()
    window = motion(4)
    for epoch in (0, 1):
        model.start_epoch(epoch, frames)
        model.zero_grad()
        terms = model.loss_terms(window[:, :T_IN], window[:, T_IN:])
        assert terms["dynamic"] is None
        loss = model.training_loss(window[:, :T_IN], window[:, T_IN:])
        loss.backward()
        assert all(p.grad is None for p in model.transformer.parameters())
        assert all(
            p.grad is not None and p.grad.abs().sum() > 0 for p in model.autoencoder.parameters()
        )

    model.start_epoch(2, frames)
    terms = model.loss_terms(window[:, :T_IN], window[:, T_IN:])
    assert terms["dynamic"] is not None and terms["dynamic"] > 0
    # the dynamic loss never reaches the autoencoder, the static loss never the transformer
    assert all(g is None for g in _grads(terms["dynamic"], model.autoencoder.parameters()))
    assert all(
        g is not None and g.abs().sum() > 0
        for g in _grads(terms["dynamic"], model.transformer.parameters())
    )
    assert all(g is None for g in _grads(terms["static"], model.transformer.parameters()))
    torch.manual_seed(5)
    total = model.training_loss(window[:, :T_IN], window[:, T_IN:])
    torch.manual_seed(5)
    terms = model.loss_terms(window[:, :T_IN], window[:, T_IN:])
    torch.testing.assert_close(total, terms["static"] + terms["dynamic"])


def test_static_loss_is_mse_of_destandardised_coefficients_in_metres():
    model = trained_stats(make(static_frames=W), epoch=0)  # every frame: no sampling
    window = motion(2)
    coeffs = model.project(window)
    with torch.no_grad():
        rebuilt = model.decode(model.encode(coeffs))
        static = model.coefficient_loss_terms(coeffs)["static"]
    torch.testing.assert_close(static, ((rebuilt - coeffs) / 1000).square().mean())


def test_engine_like_loop_leaves_the_transformer_alone_until_epoch_three():
    """As zoo.train runs it: start_epoch, then Adam steps on training_loss."""
    model = make()
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    snapshot = {n: p.detach().clone() for n, p in model.transformer.named_parameters()}
    losses = []
    for epoch in range(3):
        model.start_epoch(epoch, frames)
        for batch in WINDOW_BATCHES:
            loss = model.training_loss(batch[:, :T_IN], batch[:, T_IN:])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            losses.append(loss.item())
        moved = any(
            not torch.equal(p, snapshot[n]) for n, p in model.transformer.named_parameters()
        )
        assert moved == (epoch == 2)
    assert all(np.isfinite(losses))


# ---- inference -----------------------------------------------------------------------------------


def test_forward_shapes_and_rollout_feeds_predictions_back():
    model = trained_stats(make()).double().eval()
    history = motion(2, frames=T_IN + 3).double()
    with torch.no_grad():
        out = model(history[:, -T_IN:])
        assert out.shape == (2, T_OUT, V, 3) and out.dtype == torch.float64
        torch.testing.assert_close(model.rollout(history, 3), out[:, :3])
        long = model.rollout(history, 2 * T_OUT + 1)
        # by hand: feed the last T_IN frames (vertices) back twice
        frames, seen = [], history
        for _ in range(3):
            step = model(seen[:, -T_IN:])
            frames.append(step)
            seen = torch.cat([seen, step], dim=1)
        torch.testing.assert_close(
            long, torch.cat(frames, 1)[:, : 2 * T_OUT + 1], rtol=1e-6, atol=1e-4
        )


def test_output_is_the_decoded_prediction_in_vertices():
    model = trained_stats(make()).eval()
    history = motion(2)[:, :T_IN]
    with torch.no_grad():
        coeffs = model.predict_coefficients(model.project(history))
        torch.testing.assert_close(model(history), model.reconstruct(coeffs))
        assert coeffs.shape == (2, T_OUT, BASIS.k, 3)


# ---- errors --------------------------------------------------------------------------------------


def test_errors_name_the_argument_and_what_was_expected():
    model = make()
    with pytest.raises(
        SpecTrHuMSError,
        match=rf"history: {T_IN - 1} frames, expected {T_IN} "
        rf"\(the model's window is {W}",
    ):
        model(motion(1, frames=T_IN - 1))
    with pytest.raises(
        SpecTrHuMSError,
        match=r"training frames: expected vertices "
        r"\(B, T, 30, 3\)",
    ):
        model.start_epoch(0, lambda: iter([(motion(2), torch.ones(2, dtype=torch.int64))]))
    with pytest.raises(SpecTrHuMSError, match=r"training frames: \(3,\) counts for 4 frames"):
        model.start_epoch(
            0, lambda: iter([(motion(1, frames=4)[0], torch.ones(3, dtype=torch.int64))])
        )
    with pytest.raises(SpecTrHuMSError, match=r"expected vertices \(B, T, 30, 3\)"):
        model(torch.zeros(1, T_IN, V + 1, 3))
    with pytest.raises(SpecTrHuMSError, match=r"basis: 30 vertices .* but num_points=31"):
        SpecTrHuMS(T_IN, T_OUT, V + 1, BASIS, **SMALL)
    skewed = type("B", (), {"vectors": BASIS.vectors * 2, "hash": "x"})()
    with pytest.raises(SpecTrHuMSError, match="not orthonormal"):
        SpecTrHuMS(T_IN, T_OUT, V, skewed, **SMALL)
    with pytest.raises(SpecTrHuMSError, match="basis: expected a spectral basis"):
        SpecTrHuMS(T_IN, T_OUT, V, None, **SMALL)
    with pytest.raises(
        SpecTrHuMSError, match="task: 'forecast' unknown; valid: prediction, completion"
    ):
        make("forecast")
    with pytest.raises(SpecTrHuMSError, match="channels .* and pooling"):
        make(channels=(4, 8, 16))
    with pytest.raises(SpecTrHuMSError, match="call start_epoch"):
        model.training_loss(motion(1)[:, :T_IN], motion(1)[:, T_IN:])
    with pytest.raises(
        SpecTrHuMSError,
        match=r"final_frame: this model was trained for "
        r"prediction",
    ):
        model(motion(1)[:, :T_IN], final_frame=motion(1)[:, -1])
    with pytest.raises(
        SpecTrHuMSError, match="history: 4 frames, shorter than the model's input_frames=6"
    ):
        model.rollout(motion(1, frames=4), 10)
    completion = make("completion")
    with pytest.raises(SpecTrHuMSError, match="final_frame is required"):
        completion(motion(1)[:, :T_IN])
    with pytest.raises(SpecTrHuMSError, match=r"final_frame: expected \(B, V, 3\)"):
        completion(motion(2)[:, :T_IN], final_frame=motion(1)[:, -1])
    with pytest.raises(SpecTrHuMSError, match="rollout is long-term prediction"):
        completion.rollout(motion(1), 10)


def test_config_holds_the_hyper_parameters_as_the_model_takes_them():
    """The config's fields are the model's arguments but the basis, with the same defaults;
    the model keeps the one it built, frozen, with channels and pooling as tuples."""
    import dataclasses
    import inspect

    params = inspect.signature(SpecTrHuMS.__init__).parameters
    taken = [(p.name, p.default) for p in params.values() if p.name not in ("self", "basis")]
    held = [
        (f.name, inspect.Parameter.empty if f.default is dataclasses.MISSING else f.default)
        for f in dataclasses.fields(SpecTrHuMSConfig)
    ]
    assert taken == held
    model = make(channels=[4, 8], pooling=[6, 3], static_frames=3)
    assert model.config == SpecTrHuMSConfig(T_IN, T_OUT, V, **{**SMALL, "static_frames": 3})
    assert (model.config.channels, model.config.pooling) == ((4, 8), (6, 3))
    assert model.config.window == model.window == W
    with pytest.raises(dataclasses.FrozenInstanceError):
        model.config.latent = 8


def test_config_checks_itself_without_a_model_or_a_basis():
    with pytest.raises(SpecTrHuMSError, match=rf"static_frames={W + 1}: at most the window"):
        SpecTrHuMSConfig(T_IN, T_OUT, V, static_frames=W + 1)
    with pytest.raises(SpecTrHuMSError, match="kernel_size: odd"):
        SpecTrHuMSConfig(T_IN, T_OUT, V, kernel_size=2)
    with pytest.raises(SpecTrHuMSError, match="d_model=10: must be even .* heads=4"):
        SpecTrHuMSConfig(T_IN, T_OUT, V, d_model=10)
    with pytest.raises(SpecTrHuMSError, match="autoencoder_epochs: a non-negative integer"):
        SpecTrHuMSConfig(T_IN, T_OUT, V, autoencoder_epochs=-1)
    with pytest.raises(SpecTrHuMSError, match="loss_unit_mm: positive"):
        SpecTrHuMSConfig(T_IN, T_OUT, V, loss_unit_mm=0)
    with pytest.raises(SpecTrHuMSError, match=r"channels\[1\]: a positive integer, got 0"):
        SpecTrHuMSConfig(T_IN, T_OUT, V, channels=(4, 0))
    with pytest.raises(SpecTrHuMSError, match="num_points: a positive integer, got True"):
        SpecTrHuMSConfig(T_IN, T_OUT, True)
    # the model checks its settings before its basis
    with pytest.raises(SpecTrHuMSError, match="static_frames"):
        SpecTrHuMS(T_IN, T_OUT, V, None, **{**SMALL, "static_frames": W + 1})


# ---- checkpoints ---------------------------------------------------------------------------------


def test_checkpoint_round_trip_keeps_the_standardisation_buffers():
    model = trained_stats(make(seed=0)).eval()
    buf = io.BytesIO()
    torch.save(model.state_dict(), buf)
    buf.seek(0)
    state = torch.load(buf, weights_only=True)
    for name in (
        "coeff_mean",
        "coeff_std",
        "coeff_frames",
        "latent_mean",
        "latent_std",
        "latent_frames",
        "basis_id",
    ):
        assert name in state
    assert "phi" not in state  # the basis travels with the data, by hash
    fresh = make(seed=1).eval()
    assert not torch.equal(fresh.coeff_std, model.coeff_std)
    fresh.load_state_dict(state)
    for name in ("coeff_mean", "coeff_std", "latent_mean", "latent_std"):
        assert torch.equal(getattr(fresh, name), getattr(model, name))
    history = motion(2)[:, :T_IN]
    with torch.no_grad():
        assert torch.equal(fresh(history), model(history))

    other = GridBasis(rows=5, cols=6)  # same V and k, another mesh: another basis
    with pytest.raises(SpecTrHuMSError, match="trained with another spectral basis"):
        make(basis=other).load_state_dict(state)


def recomputed(basis, vectors):
    """``basis`` as another machine computes it: the same topology and k, so the same name."""
    return SpectralBasis(basis.topology_hash, basis.eigenvalues, vectors, basis.topology_name)


def test_weights_check_the_numbers_of_their_basis_not_only_its_name():
    state = trained_stats(make(seed=0)).state_dict()
    history = motion(2)[:, :T_IN]
    # Another machine's solver: the same basis to rounding (measured between OpenBLAS kernels:
    # 5e-13), so other bytes and the same name; the weights apply, in float16 too.
    noise = np.random.default_rng(0).standard_normal(BASIS.vectors.shape) * 1e-12
    rounded = recomputed(BASIS, BASIS.vectors + noise)
    assert rounded.hash == BASIS.hash and rounded.checksum != BASIS.checksum
    model = make(basis=rounded, seed=1).eval()
    model.load_state_dict(
        {k: v.half().float() if k == "basis_probe" else v for k, v in state.items()}
    )
    reference = make(seed=2).eval()
    reference.load_state_dict(state)
    with torch.no_grad():
        assert torch.allclose(model(history), reference(history), atol=1e-3)
    # The same name, but one eigenvector with the other sign: refused, naming the difference.
    flipped = BASIS.vectors.copy()
    flipped[:, 3] *= -1
    with pytest.raises(SpecTrHuMSError, match=r"probe projections differ by up to \d"):
        make(basis=recomputed(BASIS, flipped)).load_state_dict(state)
    # ... or two eigenvectors mixed (a rotated eigenspace)
    mixed = BASIS.vectors.copy()
    c, s = np.cos(0.3), np.sin(0.3)
    mixed[:, 5], mixed[:, 6] = (
        c * BASIS.vectors[:, 5] + s * BASIS.vectors[:, 6],
        -s * BASIS.vectors[:, 5] + c * BASIS.vectors[:, 6],
    )
    with pytest.raises(SpecTrHuMSError, match="another rotation"):
        make(basis=recomputed(BASIS, mixed)).load_state_dict(state)
    # Weights exported before the probe existed cannot be checked: refused, saying what to do.
    with pytest.raises(SpecTrHuMSError, match="carry no basis_probe .* export them again"):
        make().load_state_dict({k: v for k, v in state.items() if k != "basis_probe"})


# ---- registry ------------------------------------------------------------------------------------


def test_registry_entries_and_recipe():
    registry = load_registry()
    pred = registry.create_model(
        "spectrhums", input_frames=T_IN, output_frames=T_OUT, num_points=V, basis=BASIS, **SMALL
    )
    comp = registry.create_model(
        "spectrhums_completion",
        input_frames=T_IN,
        output_frames=T_OUT,
        num_points=V,
        basis=BASIS,
        **SMALL,
    )
    assert (pred.task, comp.task) == ("prediction", "completion")
    assert pred.k == BASIS.k and pred.window == W
    for name in ("spectrhums", "spectrhums_completion"):
        entry = registry.get(name)
        assert entry.context == ("basis",) and entry.representation == ("mesh",)
        assert entry.hparams["autoencoder_epochs"] == 2 and entry.hparams["layers"] == 6
        recipe = training_recipe(entry.train)
        assert (recipe.lr, recipe.batch_size, recipe.epochs) == (1e-4, 32, 100)
        assert learning_rate(recipe.schedule, recipe.lr, 0, 100) == pytest.approx(1e-4)
        assert learning_rate(recipe.schedule, recipe.lr, 100, 100) == pytest.approx(1e-6)


def test_position_dropout_as_in_the_public_code():
    """Dropout 0.1 after the sinusoidal positions by default: active while training, never at
    evaluation; 0 turns it off; anything outside [0, 1) is refused by name."""
    model = trained_stats(make())
    assert model.transformer.position_dropout == 0.1
    z = model.standardise_latents(model.encode(model.project(motion(2))))
    model.train()
    assert not torch.equal(model.transform_window(z), model.transform_window(z))
    model.eval()
    assert torch.equal(model.transform_window(z), model.transform_window(z))
    off = trained_stats(make(position_dropout=0.0)).train()
    assert torch.equal(off.transform_window(z), off.transform_window(z))  # dropout 0.0 elsewhere
    for bad in (1.0, -0.1, "0.1", True):
        with pytest.raises(SpecTrHuMSError, match=r"position_dropout: a probability in \[0, 1\)"):
            make(position_dropout=bad)


def test_autoencoder_floor_is_the_round_trip_of_the_given_frames():
    model = trained_stats(make()).eval()
    frames = motion(3)
    floor = model.autoencoder_floor(frames)
    with torch.no_grad():
        expected = model.reconstruct(model.decode(model.encode(model.project(frames))))
    torch.testing.assert_close(floor, expected)
    assert floor.shape == frames.shape
    with pytest.raises(SpecTrHuMSError, match=r"frames: expected vertices \(B, T, "):
        model.autoencoder_floor(frames[0])


def test_training_on_coefficients_is_training_on_vertices():
    """The engine's training view: statistics from coefficient frames and the loss of
    coefficient windows equal those computed from the vertices (static loss over every frame,
    so no random frame choice)."""
    by_vertices, by_view = make(static_frames=W), make(static_frames=W)

    def view_frames():
        for flat, counts in frames():
            yield by_view.training_view(flat).float(), counts

    for epoch in (0, 2):
        by_vertices.start_epoch(epoch, frames)
        by_view.start_epoch(epoch, view_frames, view=True)
    for name in ("coeff_mean", "coeff_std", "latent_mean", "latent_std"):
        torch.testing.assert_close(getattr(by_view, name), getattr(by_vertices, name))
    x = motion(3, seed=9)
    c = by_view.training_view(x.flatten(0, 1)).float().view(3, W, -1, 3)
    torch.manual_seed(5)  # the same dropout masks for both
    from_view = by_view.training_loss_view(c[:, :T_IN], c[:, T_IN:])
    torch.manual_seed(5)
    from_vertices = by_vertices.training_loss(x[:, :T_IN], x[:, T_IN:])
    torch.testing.assert_close(from_view, from_vertices, rtol=1e-4, atol=1e-6)
    identity = by_view.training_view_identity()
    assert identity["basis_hash"] == BASIS.hash and identity["k"] == BASIS.k
    with pytest.raises(SpecTrHuMSError, match=r"expected coefficients \(B, T, 12, 3\)"):
        by_view.start_epoch(0, frames, view=True)  # vertices where coefficients belong


def test_cost_columns_time_the_step_the_engine_runs(monkeypatch):
    """The training throughput of a model with a training view is measured on windows of it
    (zoo.leaderboard.efficiency), as zoo.train steps it: a trained model's coefficient statistics
    kept."""
    from zoo.leaderboard.efficiency import measure

    model = trained_stats(make())  # as loaded from a checkpoint: statistics, autoencoder phase
    model.phase = "autoencoder"
    kept = model.coeff_mean.clone()
    views = []
    original = SpecTrHuMS.coefficient_loss_terms

    def recorded(self, coeffs):
        views.append((self.phase, torch.equal(self.coeff_mean, kept), coeffs.shape[-2:]))
        return original(self, coeffs)

    monkeypatch.setattr(SpecTrHuMS, "coefficient_loss_terms", recorded)
    row = measure(
        model,
        input_frames=T_IN,
        output_frames=T_OUT,
        points=V,
        recipe={"batch_size": 4, "precision": "float32", "grad_clip": None, "epochs": 3},
    )
    assert row["train_samples_per_s"] > 0 and row["gflop_per_sample"] > 0
    # coefficients (the view), the joint phase of epoch 3, the trained statistics kept
    assert views and set(views) == {("joint", True, (BASIS.k, 3))}
