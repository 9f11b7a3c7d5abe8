"""DMGNN layer for layer against its public code (limaosen0/DMGNN, ``cmu-long``), and both
training steps timed side by side.

The public model is built from a checkout (``<public>/DMGNN``) with the long CMU configuration
(``config/CMU/long/train.yaml``) and initialised as its processor does (``weights_init``); the
zoo's model, built from the registry entry's hyper-parameters, loads the public state dict (the
names are the code's). Both get the same standardised batch (49 encoder frames of 78 channels
and the last three frames). The script prints the parameter counts, the largest absolute and
relative differences of the prediction in eval mode, and of the loss (the code's weighted L1
against the zoo's ``training_loss``) and every gradient in training mode with dropout off (in
float64), then the milliseconds of one training step of each (the code's: Adam, gradient-norm
clip 0.5) at the code's batch of 32 on this CPU, the two alternating step by step (the median
of ``--repeats`` after one warm-up each).

The public decoder adds Gaussian noise (std 0.0005) to its input in every mode and its
``Decoder`` moves a mask to CUDA: both are switched off (noise) or made no-ops (``.cuda()``)
while it runs here; the zoo adds the noise in training only (docs/models/dmgnn.md).

Run: python benchmarks/speed/public_dmgnn.py [--public DIR] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

import zoo
from zoo.paths import REPO_ROOT

RELATIONS = (26, 10, 5)  # the processor's fully connected graphs: joints, parts, bodies


def public_model(folder: Path):
    """The public ``Model`` of ``config/CMU/long/train.yaml`` on the CPU, initialised by the
    processor's ``weights_init``, and the six relation matrices its forward takes."""
    import yaml

    sys.path.insert(0, str(folder / "cmu-long"))
    from net.model import Model
    from processor.data_tools import encode_onehot

    config = yaml.safe_load((folder / "config" / "CMU" / "long" / "train.yaml").read_text())
    model = Model(**config["model_args"])

    def weights_init(m):  # processor/recognition.py's, applied as REC_Processor.load_model does
        name = m.__class__.__name__
        if name.find("Conv1d") != -1 or name.find("Conv2d") != -1:
            m.weight.data.normal_(0.0, 0.02)
            if m.bias is not None:
                m.bias.data.fill_(0)
        elif name.find("BatchNorm") != -1:
            m.weight.data.normal_(1.0, 0.02)
            m.bias.data.fill_(0)

    model.apply(weights_init)
    relations = []
    for nodes in RELATIONS:
        off = np.ones([nodes, nodes]) - np.eye(nodes)
        relations += [
            torch.FloatTensor(np.array(encode_onehot(np.where(off)[1]), dtype=np.float32)),
            torch.FloatTensor(np.array(encode_onehot(np.where(off)[0]), dtype=np.float32)),
        ]
    return model, relations, config["lamda"]


def public_inputs(frames: torch.Tensor, training: bool):
    """The processor's encoder and decoder inputs of standardised windows ``(N, T_in, 78)``:
    velocities, and accelerations aligned as its ``train`` (or ``test``) aligns them."""
    p = frames[:, :-1]
    v = torch.zeros_like(p)
    v[:, 1:] = p[:, 1:] - p[:, :-1]
    a = torch.zeros_like(p)
    if training:
        a[:, :-1] = v[:, 1:] - v[:, :-1]
    else:
        a[:, 1:] = v[:, 1:] - v[:, :-1]
    return p, v, a, frames[:, -1:], p[:, -1:], p[:, -2:-1]


def code_loss(outputs: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
    """processor/recognition.py's ``loss_l1`` with processor.py's mask (frames 11-25 count
    twice), on ``(N, V, T, 3)``."""
    mask = torch.ones(outputs.shape[2], dtype=outputs.dtype)
    mask[10:] = 2
    return torch.mean(torch.abs(outputs - targets).mean(-1).mean(1).mean(0) * mask)


def as_angles(model, channels: torch.Tensor) -> torch.Tensor:
    """Standardised channels ``(N, T, 78)`` as the zoo model's exp-map frames ``(N, T, 38,
    3)``, its mean 0 and std 1 (so that its standardisation gives the channels back)."""
    angles = channels.new_zeros(*channels.shape[:2], model.num_points * 3)
    angles[..., model.channels] = channels
    return angles.view(*channels.shape[:2], model.num_points, 3)


def _set_dropout(model, p: float) -> None:
    for m in model.modules():
        if isinstance(m, torch.nn.Dropout) or type(m).__name__ == "Dropout":
            m.p = p
            if hasattr(m, "threshold"):
                m.threshold = round(p * 65536)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--public", type=Path, default=REPO_ROOT.parent / "public")
    parser.add_argument("--repeats", type=int, default=5, help="timed steps (median)")
    args = parser.parse_args(argv)
    folder = args.public / "DMGNN"
    if not folder.is_dir():
        print(f"dmgnn: no public checkout at {folder}; skipped")
        return 1
    cuda, randn = torch.Tensor.cuda, torch.randn
    torch.Tensor.cuda = lambda self, *a, **k: self  # the public decoder's mask ends in .cuda()
    try:
        torch.manual_seed(0)
        theirs, relations, lamda = public_model(folder)
        ours = zoo.create_model("dmgnn", benchmark="cmu50")
        missing = ours.load_state_dict(theirs.state_dict(), strict=False)
        own = {"mean", "std"}  # the zoo's standardisation, kept apart
        if missing.unexpected_keys or set(missing.missing_keys) - own:
            print(f"dmgnn: state dicts differ: {missing}")
            return 1
        t_out = ours.output_frames
        count = {
            "public": sum(p.numel() for p in theirs.parameters()),
            "zoo": sum(p.numel() for p in ours.parameters()),
        }
        print(
            f"dmgnn against the public code (cmu-long, {t_out} frames out): parameters "
            f"{count['public']:,} public, {count['zoo']:,} zoo"
        )
        g = torch.Generator().manual_seed(1)
        frames = torch.randn(32, ours.input_frames, 78, generator=g).cumsum(1) * 0.1
        target = torch.randn(32, t_out, 78, generator=g)
        target_public = target.view(32, t_out, 26, 3).permute(0, 2, 1, 3)

        def run_public(training: bool):
            return theirs(*public_inputs(frames, training), t_out, *relations, lamda)

        torch.randn = lambda *a, **k: torch.zeros(*a, **k)  # the decoder's noise off
        try:
            theirs.eval()
            ours.eval()
            with torch.no_grad():
                a = run_public(False).permute(0, 2, 1, 3)
                b = ours.network(frames, t_out)
            gap = (a - b).abs().max().item()
            print(
                f"  prediction (eval): largest difference {gap:.3g}, relative "
                f"{gap / a.abs().max().item():.3g} (values up to {a.abs().max():.3g})"
            )
            # float64: the first layers' bias gradients pass BatchNorm as a near-cancelling sum,
            # whose float32 rounding differs between any two orders of summation
            for model in (theirs, ours):
                model.double().train()
                _set_dropout(model, 0.0)
                model.zero_grad()
            ours.decoder.noise = 0.0
            doubled = [r.double() for r in relations]
            inputs = [x.double() for x in public_inputs(frames.double(), True)]
            out = theirs(*inputs, t_out, *doubled, lamda)
            loss_public = code_loss(out, target_public.double())
            loss_public.backward()
            loss_zoo = ours.training_loss(
                as_angles(ours, frames.double()), as_angles(ours, target.double())
            )
            loss_zoo.backward()
        finally:
            torch.randn = randn
            theirs.float()
        grads = dict(ours.named_parameters())
        gaps = {
            n: (p.grad - grads[n].grad).abs().max().item() for n, p in theirs.named_parameters()
        }
        worst = max(gaps, key=gaps.get)
        scale = max(p.grad.abs().max().item() for p in theirs.parameters())
        print(
            f"  loss (training mode, dropout off, float64): {loss_public.item():.15f} public, "
            f"{loss_zoo.item():.15f} zoo"
        )
        print(
            f"  gradients: largest difference {gaps[worst]:.3g} ({worst}; largest gradient "
            f"{scale:.3g})"
        )
        _set_dropout(theirs, 0.5)  # back to the code's rates, as trained
        ours = zoo.create_model("dmgnn", benchmark="cmu50")
        ours.load_state_dict(theirs.state_dict(), strict=False)
        ours.train()
        history, future = as_angles(ours, frames), as_angles(ours, target)
        steps = {
            "public": (theirs, lambda: code_loss(run_public(True), target_public)),
            "zoo": (ours, lambda: ours.training_loss(history, future)),
        }
        optimizers = {
            name: torch.optim.Adam(model.parameters(), lr=5e-5, weight_decay=1e-4)
            for name, (model, _) in steps.items()
        }
        runs = {name: [] for name in steps}
        # the two alternate, step by step, so that a machine's changing load falls on both
        for _ in range(args.repeats + 1):
            for name, (model, loss) in steps.items():
                model.train()
                started = time.perf_counter()
                optimizers[name].zero_grad()
                loss().backward()
                torch.nn.utils.clip_grad_norm_(model.parameters(), 0.5)
                optimizers[name].step()
                runs[name].append(time.perf_counter() - started)
        times = {name: statistics.median(r[1:]) for name, r in runs.items()}
        print(
            f"  training step, batch 32, {torch.get_num_threads()} thread(s): public "
            f"{times['public'] * 1e3:.0f} ms, zoo {times['zoo'] * 1e3:.0f} ms "
            f"(zoo / public {times['zoo'] / times['public']:.2f})"
        )
    finally:
        torch.Tensor.cuda = cuda
    return 0


if __name__ == "__main__":
    sys.exit(main())
