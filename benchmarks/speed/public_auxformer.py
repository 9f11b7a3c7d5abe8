"""AuxFormer against its public code (MediaBrain-SJTU/AuxFormer), and both training steps timed.

The public model is built from a checkout (``<public>/AuxFormer``, as ``speed_public_cmu.py``
finds the others) with its long CMU configuration (``cfg/cmu_long.yml``, the arguments
``main_cmu.py`` passes), on the CPU (its ``.cuda()`` calls made no-ops while it runs). The zoo's
model, built from the registry, loads the public model's state dict (the names and shapes are
the same by design). Both get one batch of 16 windows in the code's units (mm / 100):

- prediction: the public ``predict`` against the zoo's ``predict_units``;
- training loss: the public forward and ``main_cmu.py``'s loss, its random draws (the hidden
  tokens, the noise deviation, the Gaussian and the noised share) recorded as it makes them and
  given to the zoo's ``corrupted_loss``; then every parameter's gradient;
- one training step of each (forward with the zoo's or the code's own draws, loss, backward,
  Adam), timed in turn, each first every other pair, so that they share the machine's load.

Run: python benchmarks/speed/public_auxformer.py [--public DIR] [--repeats 5] [--threads 1]
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
from zoo.models.auxformer import Corruption
from zoo.paths import REPO_ROOT

PAST, FUTURE, JOINTS, BATCH = 10, 13, 25, 16


def public_model(folder: Path):
    """The public AuxFormer as ``main_cmu.py --task long`` builds it, and its configuration."""
    import yaml

    sys.path.insert(0, str(folder))
    from model.model import AuxFormer

    c = yaml.safe_load((folder / "cfg" / "cmu_long.yml").read_text())
    names = (
        "mask_ratio decoder_dim encoder_depth decoder_depth same_head range_mask_ratio mlp_head "
        "mask_past mask_range multi_output decoder_masking pred_all mlp_dim dim_per_head "
        "noise_dev part_noise denoise_mode part_noise_ratio add_joint_token concat_vel "
        "concat_acc only_recons_past add_residual denoise regular_masking multi_same_head "
        "range_noise_dev"
    ).split()
    model = AuxFormer(
        in_dim=2,
        h_dim=c["nf"],
        past_timestep=PAST,
        future_timestep=c["future_length"],
        num_heads=8,
        decoder_dim_per_head=c["dim_per_head"],
        n_agent=JOINTS,
        **{name: c[name] for name in names},
    )
    return model, c


def code_loss(model, past, future, config):
    """``main_cmu.py``'s ``train`` body: the forward on observed and true future frames, the
    heads' mean error over the depth, the masked tokens' error and the denoised one's."""
    prediction, recovered, masked, denoised, hidden = model(torch.cat([past, future], dim=2))
    loss = 0
    for item in prediction:
        loss += torch.mean(torch.norm(item - future, dim=-1)) / config["encoder_depth"]
    loss += torch.sum(torch.norm(recovered - masked, dim=-1, p=2)) / torch.sum(hidden)
    return loss + torch.mean(torch.norm(denoised - past, dim=-1)), hidden


class Recorder:
    """Records what ``torch.rand``, ``np.random.normal`` and ``np.random.uniform`` return while
    it is entered, so that the zoo's loss can be given the public forward's very draws."""

    def __enter__(self):
        self.rand, self.normal, self.uniform = torch.rand, np.random.normal, np.random.uniform
        self.drawn = {"rand": [], "normal": [], "uniform": []}

        def keep(name, draw):
            def wrapped(*args, **kwargs):
                value = draw(*args, **kwargs)
                self.drawn[name].append(value)
                return value

            return wrapped

        torch.rand = keep("rand", self.rand)
        np.random.normal = keep("normal", self.normal)
        np.random.uniform = keep("uniform", self.uniform)
        return self

    def __exit__(self, *exc):
        torch.rand, np.random.normal, np.random.uniform = self.rand, self.normal, self.uniform


def batch(generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """Observed and future coordinates ``(B, N, T, 3)`` in mm / 100: random walks about a body."""
    body = torch.randn(BATCH, JOINTS, 1, 3, generator=generator) * 3.0
    steps = torch.randn(BATCH, JOINTS, PAST + FUTURE, 3, generator=generator) * 0.2
    trajectory = body + steps.cumsum(dim=2)
    return trajectory[:, :, :PAST], trajectory[:, :, PAST:]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--public", type=Path, default=REPO_ROOT.parent / "public")
    parser.add_argument("--repeats", type=int, default=5, help="timed steps (median)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    folder = args.public / "AuxFormer"
    if not folder.is_dir():
        print(f"auxformer: no public checkout at {folder} (see speed_public_cmu.py); skipped")
        return 0
    torch.set_num_threads(args.threads)
    cuda = torch.Tensor.cuda
    torch.Tensor.cuda = lambda self, *a, **k: self  # the public forward moves indices .cuda()
    try:
        torch.manual_seed(0)
        np.random.seed(0)
        theirs, config = public_model(folder)
        ours = zoo.create_model("auxformer", benchmark="cmu")
        ours.load_state_dict(theirs.state_dict())
        count = sum(p.numel() for p in theirs.parameters())
        past, future = batch(torch.Generator().manual_seed(1))
        trajectory = torch.cat([past, future], dim=2)
        theirs.eval(), ours.eval()
        with torch.no_grad():
            public = theirs.predict(torch.cat([past, torch.zeros_like(future)], dim=2))
            zoo_side = ours.predict_units(trajectory)
        gap = (public - zoo_side).abs().max().item()
        largest = public.abs().max().item()
        print(
            f"auxformer against the public code (long CMU model, {count:,} public parameters, "
            f"{sum(p.numel() for p in ours.parameters()):,} zoo, the same state dict):"
        )
        print(
            f"  prediction: largest difference {gap:.3g}, relative {gap / largest:.3g} (values "
            f"up to {largest:.3g}, units of mm / 100)"
        )
        theirs.train(), ours.train()
        with Recorder() as drawn:
            public_loss, hidden = code_loss(theirs, past, future, config)
        public_loss.backward()
        noise = torch.from_numpy(drawn.drawn["normal"][0]).float()
        kept = drawn.drawn["rand"][1] < config["part_noise_ratio"]
        corruption = Corruption((1 - hidden)[:, :, :PAST], noise * kept[..., None])
        zoo_loss = ours.corrupted_loss(trajectory, corruption)
        zoo_loss.backward()
        ours_grads = dict(ours.named_parameters())
        grad = max(
            (p.grad - ours_grads[n].grad).abs().max().item() for n, p in theirs.named_parameters()
        )
        largest = max(p.grad.abs().max().item() for p in theirs.parameters())
        print(
            f"  training loss, the public draws replayed: {public_loss.item():.7f} public, "
            f"{zoo_loss.item():.7f} zoo, difference {abs(public_loss - zoo_loss).item():.3g}"
        )
        print(f"  gradients: largest difference {grad:.3g} (largest gradient {largest:.3g})")
        losses = {
            "public": lambda: code_loss(theirs, past, future, config)[0],
            "zoo": lambda: ours.corrupted_loss(trajectory, ours.draw_corruption(trajectory)),
        }
        optimizers = {
            name: torch.optim.Adam(model.parameters(), lr=5e-4, weight_decay=5e-6)
            for name, model in (("public", theirs), ("zoo", ours))
        }
        runs = {name: [] for name in losses}
        for repeat in range(args.repeats + 1):  # the two in turn; the first pair warms up
            # each goes first every other pair, so neither always follows the other's work
            for name in ("public", "zoo") if repeat % 2 else ("zoo", "public"):
                loss = losses[name]
                started = time.perf_counter()
                optimizers[name].zero_grad()
                loss().backward()
                optimizers[name].step()
                runs[name].append(time.perf_counter() - started)
        times = {name: statistics.median(values[1:]) for name, values in runs.items()}
        print(
            f"  training step, batch {BATCH}, {torch.get_num_threads()} thread(s): public "
            f"{times['public'] * 1e3:.0f} ms, zoo {times['zoo'] * 1e3:.0f} ms "
            f"(zoo over public {times['zoo'] / times['public']:.2f})"
        )
    finally:
        torch.Tensor.cuda = cuda
    return 0


if __name__ == "__main__":
    sys.exit(main())
