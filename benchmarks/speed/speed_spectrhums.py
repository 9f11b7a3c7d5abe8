"""Speed of SpecTrHuMS in its published configuration, against the public code's figures.

Configuration: the registry entry ``spectrhums`` (latent 256, 6 layers, 4 heads, feed-forward
1024, pooling 64/32), window 75 = 50 observed + 25 predicted, k = 512 coefficients on 6,890
vertices (SMPL's size). The basis is a RANDOM orthonormal 6890 x 512 matrix (QR of a Gaussian
matrix), not a Laplacian eigenbasis: the cost of every step is the same for any orthonormal
basis of that size. Inputs are random vertices in mm.

Measured (medians of ``--repeats`` runs after one warm-up, wall clock):
- parameters;
- training samples per second at batch 32 (forward + backward + Adam step, joint phase: static
  and dynamic losses), from coefficients and from vertices (the projection of 32 x 75 frames
  included); the autoencoder-only phase (first 2 epochs) for reference; and the coefficient
  step in mixed precision, as the training recipe's ``precision: bfloat16`` runs it (the loss
  under ``torch.autocast(bfloat16)``, float32 weights and optimiser);
- inference latency at batch 1 and 32, coefficients in / coefficients out and vertices in /
  vertices out;
- mesh reconstruction of 25 predicted frames x 32 windows: one reshaped matrix product against
  one product per frame;
- start_epoch's statistics (coefficients, then latents) over the windows of a 150-frame motion
  cut by sampler ``all``: each distinct frame once with the number of windows holding it, as
  the engine gives them, against every frame of every window one by one, timed alternately,
  with the largest difference between the two results (relative);
- the same model computed layer by layer with stock torch modules (``nn.Conv1d``, the pooling
  matrices, ``nn.TransformerEncoder``), timed alternately with the zoo's: a same-load ratio.
FLOPs come from ``torch.utils.flop_counter``; the machine's matrix-product rate is measured in
the same run (a 2400 x 256 by 256 x 1024 product), so the figures can be read against what the
machine delivered while they were taken (the machine is shared: see the load average).

Run: python benchmarks/speed/speed_spectrhums.py [--repeats 5] [--threads N]
(``--vertices``, ``--k`` and ``--tiny``, a model of a few thousand parameters, make a quick check
of the script, not a measurement of the published configuration.)
On a loaded machine, two threads wait on each other at every operation (small batches suffer
most); ``--threads 1`` then gives steadier figures.
"""

import argparse
import os
import statistics
import time

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.flop_counter import FlopCounterMode

from zoo.data.spectral import SpectralBasis
from zoo.data.windows import frame_counts, gather_windows, window_sampler
from zoo.models.registry import load_registry
from zoo.train.step import forward_precision

V, K, T_IN, T_OUT, BATCH = 6890, 512, 50, 25, 32
TINY = {
    "latent": 16,
    "channels": [4, 8],
    "pooling": [8, 4],
    "d_model": 16,
    "layers": 1,
    "heads": 2,
    "ff": 32,
}
STATS_FRAMES = 150  # a motion of 6 s at 25 Hz: 76 windows of 75 frames
# The public SpecTrHuMS code on this machine type (figures given with the task).
PUBLIC = {
    "params": 6.0e6,
    "latency_b1_ms": 14.0,
    "latency_b32_ms": 542.0,
    "train_step_ms": 536.0,
    "train_samples_s": 60.0,
    "reconstruction_loop_s": 0.7,
}


def random_basis(v: int, k: int, seed: int = 0) -> SpectralBasis:
    """A random orthonormal basis (same cost as a Laplacian eigenbasis of that size)."""
    g = torch.Generator().manual_seed(seed)
    q, _ = torch.linalg.qr(torch.randn(v, k, dtype=torch.float64, generator=g))
    return SpectralBasis(
        f"random-{v}x{k}-seed{seed}", np.arange(k, dtype=float), q.numpy(), "random"
    )


def median_seconds(fn, repeats: int, warm_up: bool = True) -> float:
    if warm_up:
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def paired_medians(fn_a, fn_b, repeats: int) -> tuple[float, float]:
    """Medians of two workloads timed alternately, so both see the same machine load."""
    fn_a(), fn_b()
    a, b = [], []
    for _ in range(repeats):
        for fn, times in ((fn_a, a), (fn_b, b)):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
    return statistics.median(a), statistics.median(b)


class LayerByLayer(nn.Module):
    """The same model and weights, computed the textbook way: per encoder level ``nn.Conv1d``
    then the pooling matrix on ``(N, C, k)`` (decoder: unpooling then ``nn.Conv1d``), and torch's
    ``nn.TransformerEncoder`` (post-norm, sequence-first). The baseline for the zoo's
    arrangement of the same sums, timed in the same run."""

    def __init__(self, model) -> None:
        super().__init__()
        self.model = model
        t = model.transformer
        first = t.layers[0]
        layer = nn.TransformerEncoderLayer(
            first.qkv.in_features, first.heads, first.ff1.out_features, 0.0, activation="gelu"
        )
        self.encoder = nn.TransformerEncoder(layer, len(t.layers), enable_nested_tensor=False)
        with torch.no_grad():
            for ref, mine in zip(self.encoder.layers, t.layers):
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

    def encode(self, coeffs: torch.Tensor) -> torch.Tensor:
        m, ae = self.model, self.model.autoencoder
        h = m.standardise_coefficients(coeffs).reshape(-1, m.k, 3).transpose(1, 2)
        for conv, pool in zip(ae.encoder_convs, ae.encoder_pools):
            h = F.elu(pool(conv(h)))
        return ae.to_latent(h.flatten(1)).view(*coeffs.shape[:-2], -1)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        m, ae = self.model, self.model.autoencoder
        h = ae.from_latent(z.reshape(-1, z.shape[-1])).view(-1, *ae.bottleneck)
        for pool, conv in zip(ae.decoder_pools, ae.decoder_convs):
            h = F.elu(conv(pool(h)))
        out = ae.to_coordinates(h).transpose(1, 2)
        return m.destandardise_coefficients(out).view(*z.shape[:-1], m.k, 3)

    def transform(self, x: torch.Tensor) -> torch.Tensor:
        t = self.model.transformer
        h = (t.inp(x) + t.positions[: x.shape[1]]).transpose(0, 1)
        return t.out(self.encoder(h).transpose(0, 1))

    def loss(self, coeffs: torch.Tensor) -> torch.Tensor:
        m = self.model
        b = coeffs.shape[0]
        picked = coeffs[torch.arange(b), torch.randint(0, m.window, (b,))]
        static = F.mse_loss(
            self.decode(self.encode(picked)) / m.loss_unit_mm, picked / m.loss_unit_mm
        )
        with torch.no_grad():
            target = m.standardise_latents(self.encode(coeffs))
        return static + F.mse_loss(self.transform(m.masked_window(target)), target)

    def predict(self, coeffs: torch.Tensor) -> torch.Tensor:
        m = self.model
        z = m.standardise_latents(self.encode(coeffs))
        out = self.transform(m.fill_window(z))[:, m.input_frames :]
        return self.decode(m.destandardise_latents(out))


def flops(fn) -> float:
    with FlopCounterMode(display=False) as counter:
        fn()
    return float(counter.get_total_flops())


def gemm_rate(repeats: int) -> float:
    a, b = torch.randn(2400, 256), torch.randn(256, 1024)
    seconds = median_seconds(lambda: [a @ b for _ in range(10)], repeats) / 10
    return 2 * 2400 * 256 * 1024 / seconds / 1e9


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument(
        "--threads", type=int, default=None, help="torch threads (default: torch's own choice)"
    )
    parser.add_argument("--vertices", type=int, default=V, help="vertices of the random basis")
    parser.add_argument("--k", type=int, default=K, help="coefficients of the random basis")
    parser.add_argument(
        "--tiny",
        action="store_true",
        help=f"a tiny model ({', '.join(f'{n} {x}' for n, x in TINY.items())})",
    )
    args = parser.parse_args(argv)
    v, k = args.vertices, args.k
    if args.threads:
        torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    load0 = os.getloadavg()[0]
    rate0 = gemm_rate(args.repeats)

    t0 = time.perf_counter()
    basis = random_basis(v, k)
    basis_s = time.perf_counter() - t0
    registry = load_registry()
    hparams = {**registry.get("spectrhums").hparams, **(TINY if args.tiny else {})}
    model = registry.create_model(
        "spectrhums",
        input_frames=T_IN,
        output_frames=T_OUT,
        num_points=v,
        basis=basis,
        **(TINY if args.tiny else {}),
    )
    params = sum(p.numel() for p in model.parameters())

    g = torch.Generator().manual_seed(1)
    vertices = torch.randn(BATCH, T_IN + T_OUT, v, 3, generator=g) * 100.0
    # start_epoch's statistics over every frame of every window of a STATS_FRAMES-frame motion
    # cut by sampler all: each distinct frame once with its window count (the engine) against
    # every window's frames one by one (as the engine gave them before), same model.
    motion = torch.cumsum(torch.randn(STATS_FRAMES, v, 3, generator=g), 0) + vertices[0, :1]
    index = window_sampler("all", [STATS_FRAMES], T_IN, T_OUT)
    counts = torch.from_numpy(frame_counts(index, [STATS_FRAMES], T_IN + T_OUT)[0])
    per_window = torch.from_numpy(gather_windows([motion.numpy()], index, T_IN + T_OUT))

    def statistics_pass(batches):
        def run():
            model.start_epoch(0, lambda: iter(batches))  # coefficient statistics
            model.start_epoch(2, lambda: iter(batches))  # and latent ones (joint phase)
            return [
                b.clone()
                for b in (model.coeff_mean, model.coeff_std, model.latent_mean, model.latent_std)
            ]

        return run

    counted = statistics_pass([(motion, counts)])
    windowed = statistics_pass(
        [(w, torch.ones(len(w), dtype=torch.int64)) for w in per_window.flatten(0, 1).split(600)]
    )
    stats_counted, stats_windowed = paired_medians(counted, windowed, max(1, args.repeats // 5))
    stats_differ = max(
        ((a - b).abs().max() / b.abs().max()).item() for a, b in zip(counted(), windowed())
    )
    coeffs = model.project(vertices)
    history, future = vertices[:, :T_IN], vertices[:, T_IN:]

    baseline = LayerByLayer(model)
    model.eval()  # the positional-encoding dropout off: the same sums on both sides
    with torch.no_grad():
        same = (
            (baseline.predict(coeffs[:4, :T_IN]) - model.predict_coefficients(coeffs[:4, :T_IN]))
            .abs()
            .max()
            .item()
        )
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-4)
    # the baseline trains the same weights, its own copy of the transformer layers
    baseline_optimizer = torch.optim.Adam(baseline.parameters(), lr=1e-4)

    def step(loss_fn, opt=optimizer):
        def run():
            loss = loss_fn()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()

        return run

    def coeff_loss():
        terms = model.coefficient_loss_terms(coeffs)
        return terms["static"] + terms["dynamic"]

    model.train()
    train_c, train_base = paired_medians(
        step(coeff_loss), step(lambda: baseline.loss(coeffs), baseline_optimizer), args.repeats
    )
    train_v = median_seconds(step(lambda: model.training_loss(history, future)), args.repeats)
    train_flops = flops(step(coeff_loss))

    def coeff_loss_bf16():
        with forward_precision("bfloat16", "cpu"):  # as zoo.train runs the recipe's loss
            return coeff_loss()

    train_bf16 = median_seconds(step(coeff_loss_bf16), args.repeats)
    model.phase = "autoencoder"
    train_ae = median_seconds(
        step(lambda: model.coefficient_loss_terms(coeffs)["static"]), args.repeats
    )
    model.phase = "joint"

    model.eval()
    with torch.inference_mode():
        lat = {}
        for b in (1, BATCH):
            lat[("coeffs", b)], lat[("baseline", b)] = paired_medians(
                lambda b=b: model.predict_coefficients(coeffs[:b, :T_IN]),
                lambda b=b: baseline.predict(coeffs[:b, :T_IN]),
                args.repeats,
            )
            lat[("vertices", b)] = median_seconds(lambda b=b: model(history[:b]), args.repeats)
        infer_flops = flops(lambda: model.predict_coefficients(coeffs[:, :T_IN]))
        predicted = model.predict_coefficients(coeffs[:, :T_IN])  # (32, 25, 512, 3)
        phi = basis.torch_vectors()

        frames = predicted.reshape(-1, k, 3)
        looped = torch.empty(len(frames), v, 3)

        def per_frame():
            for i in range(len(frames)):
                torch.mm(phi, frames[i], out=looped[i])

        one = median_seconds(lambda: model.reconstruct(predicted), args.repeats)
        loop = median_seconds(per_frame, max(1, args.repeats // 2), warm_up=False)  # slow
        torch.testing.assert_close(
            looped.view(BATCH, T_OUT, v, 3), model.reconstruct(predicted), rtol=1e-4, atol=1e-2
        )
    rate1 = gemm_rate(args.repeats)
    load1 = os.getloadavg()[0]

    samples_c, samples_v = BATCH / train_c, BATCH / train_v
    print(
        f"SpecTrHuMS speed, {'tiny' if args.tiny else 'published'} configuration: k={k} "
        f"coefficients on V={v} vertices (random orthonormal basis, QR {basis_s:.1f} s), "
        f"window {T_IN}+{T_OUT}, latent {hparams['latent']}, {hparams['layers']} layers, "
        f"{hparams['heads']} heads, ff {hparams['ff']}"
    )
    print(
        f"torch {torch.__version__}, {torch.get_num_threads()} threads, "
        f"{args.repeats} repeats (medians), load average {load0:.1f} -> {load1:.1f}, "
        f"matrix products {rate0:.0f} -> {rate1:.0f} GFLOP/s"
    )
    print()
    public_vertices_ms = PUBLIC["latency_b32_ms"] + PUBLIC["reconstruction_loop_s"] * 1e3
    rows = [
        (
            "parameters",
            f"{params / 1e6:.3f} M",
            f"{PUBLIC['params'] / 1e6:.1f} M",
            f"{params / PUBLIC['params']:.2f}x",
        ),
        (
            "train step b32, coefficients in (ms)",
            f"{train_c * 1e3:.0f}",
            f"{PUBLIC['train_step_ms']:.0f}",
            "",
        ),
        (
            "train samples/s, coefficients in",
            f"{samples_c:.1f}",
            f"{PUBLIC['train_samples_s']:.0f}",
            f"{samples_c / PUBLIC['train_samples_s']:.2f}x",
        ),
        (
            "train samples/s, vertices in",
            f"{samples_v:.1f}",
            f"{PUBLIC['train_samples_s']:.0f}",
            f"{samples_v / PUBLIC['train_samples_s']:.2f}x",
        ),
        ("train samples/s, autoencoder phase", f"{BATCH / train_ae:.0f}", "", ""),
        (
            "train samples/s, coefficients in, precision bfloat16",
            f"{BATCH / train_bf16:.1f}",
            f"{PUBLIC['train_samples_s']:.0f}",
            f"{BATCH / train_bf16 / PUBLIC['train_samples_s']:.2f}x",
        ),
        (
            "latency b1, coefficients (ms)",
            f"{lat[('coeffs', 1)] * 1e3:.1f}",
            f"{PUBLIC['latency_b1_ms']:.0f}",
            f"{PUBLIC['latency_b1_ms'] / (lat[('coeffs', 1)] * 1e3):.2f}x",
        ),
        (
            "latency b32, coefficients (ms)",
            f"{lat[('coeffs', BATCH)] * 1e3:.0f}",
            f"{PUBLIC['latency_b32_ms']:.0f}",
            f"{PUBLIC['latency_b32_ms'] / (lat[('coeffs', BATCH)] * 1e3):.2f}x",
        ),
        ("latency b1, vertices (ms)", f"{lat[('vertices', 1)] * 1e3:.1f}", "", ""),
        (
            "latency b32, vertices (ms)",
            f"{lat[('vertices', BATCH)] * 1e3:.0f}",
            f"{public_vertices_ms:.0f}*",
            f"{public_vertices_ms / (lat[('vertices', BATCH)] * 1e3):.2f}x",
        ),
        ("reconstruction 25x32 frames, one product (ms)", f"{one * 1e3:.1f}", "", ""),
        (
            "reconstruction 25x32 frames, per frame (ms)",
            f"{loop * 1e3:.1f}",
            f"~{PUBLIC['reconstruction_loop_s'] * 1e3:.0f}",
            f"one product {loop / one:.1f}x",
        ),
        (
            f"start_epoch statistics, {len(index)} windows (s)",
            f"{stats_counted:.2f}",
            f"{stats_windowed:.2f}**",
            f"zoo speed-up {stats_windowed / stats_counted:.1f}x",
        ),
    ]
    rows += [
        (
            "layer-by-layer baseline, train step b32 (ms)",
            f"{train_base * 1e3:.0f}",
            "",
            f"zoo speed-up {train_base / train_c:.2f}x",
        ),
        (
            "layer-by-layer baseline, latency b1 (ms)",
            f"{lat[('baseline', 1)] * 1e3:.1f}",
            "",
            f"zoo speed-up {lat[('baseline', 1)] / lat[('coeffs', 1)]:.2f}x",
        ),
        (
            "layer-by-layer baseline, latency b32 (ms)",
            f"{lat[('baseline', BATCH)] * 1e3:.0f}",
            "",
            f"zoo speed-up {lat[('baseline', BATCH)] / lat[('coeffs', BATCH)]:.2f}x",
        ),
    ]
    width = max(len(r[0]) for r in rows)
    print(f"{'':{width}}  {'zoo':>10}  {'public':>10}  ratio (zoo vs public)")
    for name, ours, public, ratio in rows:
        print(f"{name:{width}}  {ours:>10}  {public:>10}  {ratio}")
    print(
        "* public: coefficients b32 plus its frame-by-frame reconstruction; the public code "
        "takes coefficients, so its projection of the input is not counted"
    )
    print(
        f"** every frame of every window one by one (how the engine gave them before), "
        f"{int(counts.sum())} frames against {STATS_FRAMES} counted ones; the statistics "
        f"differ by at most {stats_differ:.1e} relative"
    )
    print(
        "precision bfloat16: the training recipe's mixed precision (--train-set "
        "precision=bfloat16): the loss under torch.autocast(bfloat16), weights, optimiser and "
        "evaluation float32; the published training is float32"
    )
    print(
        f"layer-by-layer baseline: the same weights and sums computed with nn.Conv1d and "
        f"nn.TransformerEncoder, timed alternately with the zoo's (same load); predictions "
        f"agree to {same:.1e} mm"
    )
    print()
    print(
        f"train step (coefficients in): {train_flops / 1e9:.1f} GFLOP -> "
        f"{train_flops / train_c / 1e9:.0f} GFLOP/s here; the public figure "
        f"({PUBLIC['train_step_ms']:.0f} ms) implies "
        f"{train_flops / (PUBLIC['train_step_ms'] / 1e3) / 1e9:.0f} GFLOP/s for the same work"
    )
    floor = train_flops / (max(rate0, rate1) * 1e9)
    print(
        f"floor for that step if every FLOP ran at the best matrix-product rate measured "
        f"({max(rate0, rate1):.0f} GFLOP/s): {floor * 1e3:.0f} ms = {BATCH / floor:.0f} "
        f"samples/s = {BATCH / floor / PUBLIC['train_samples_s']:.2f}x the public figure"
    )
    print(
        f"inference b32 (coefficients): {infer_flops / 1e9:.1f} GFLOP -> "
        f"{infer_flops / lat[('coeffs', BATCH)] / 1e9:.0f} GFLOP/s here; the public figure "
        f"implies {infer_flops / (PUBLIC['latency_b32_ms'] / 1e3) / 1e9:.0f} GFLOP/s"
    )


if __name__ == "__main__":
    main()
