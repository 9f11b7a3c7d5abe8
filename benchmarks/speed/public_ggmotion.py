"""GGMotion layer for layer against its public code (inkcat520/GGMotion), and both steps timed.

The public model is built from a checkout (``<public>/GGMotion``, as ``speed_public_cmu.py`` finds
the others) with the long CMU configuration (``cfg/cmu_long.yml``) and the graph its CMU loader
makes; the zoo's model, built from the registry, loads the public model's state dict (the names
and shapes are the same by design), with the zero-initialised field scales drawn at random so
that every path counts. Both then get the same batch, in the code's units (mm / 1000), and the
script prints the largest differences of the prediction, of the loss (the code's trainer: mean L2
error plus the L1 bone error) and of every parameter's gradient, and the milliseconds of one
training step of each at batch 64 on this CPU.

Run: python benchmarks/speed/public_ggmotion.py [--public DIR] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import types
from pathlib import Path

import numpy as np
import torch

import zoo
from zoo.paths import REPO_ROOT

# the public code's CMU loader's groups, before group_attr adds each pair's depth in its group
CMU_GROUPS = {
    "spine": [[8, 8], [8, 9]],
    "head": [[9, 10], [10, 11], [11, 12]],
    "arm_l": [[9, 13], [13, 14], [14, 15], [15, 18], [15, 16], [16, 17]],
    "arm_r": [[9, 19], [19, 20], [20, 21], [21, 24], [21, 22], [22, 23]],
    "leg_l": [[8, 0], [0, 1], [1, 2], [2, 3]],
    "leg_r": [[8, 4], [4, 5], [5, 6], [6, 7]],
}


def public_model(folder: Path):
    """The public GGMNet of the long CMU configuration, its bone pairs, on the CPU (its
    embedding's ``.cuda()`` call made a no-op while it runs)."""
    import yaml

    sys.path.insert(0, str(folder))
    from module.model import GGMNet
    from utils.data_utils import edge_attr, group_attr

    config = types.SimpleNamespace(**yaml.safe_load((folder / "cfg" / "cmu_long.yml").read_text()))
    group = group_attr({k: np.array(v) for k, v in CMU_GROUPS.items()})
    names = ("head", "arm_l", "arm_r", "leg_l", "leg_r")
    graph = np.concatenate([group["spine"][1:], *(group[k] for k in names)], axis=0)
    edges = np.unique(edge_attr(graph, 25, config.n_hop), axis=0)
    return GGMNet(config, group, edges), np.unique(graph[:, :2], axis=0)


def code_loss(prediction, target, bones):
    error = torch.norm(target - prediction, 2, 2).mean()
    moved = prediction[:, bones[:, 1]] - prediction[:, bones[:, 0]]
    true = target[:, bones[:, 1]] - target[:, bones[:, 0]]
    return error + torch.norm(true - moved, 1, 2).mean()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--public", type=Path, default=REPO_ROOT.parent / "public")
    parser.add_argument("--repeats", type=int, default=5, help="timed steps (median)")
    args = parser.parse_args(argv)
    folder = args.public / "GGMotion"
    if not folder.is_dir():
        print(f"ggmotion: no public checkout at {folder} (see speed_public_cmu.py); skipped")
        return 0
    cuda = torch.Tensor.cuda
    torch.Tensor.cuda = lambda self, *a, **k: self  # the public embedding ends in .cuda()
    try:
        torch.manual_seed(0)
        theirs, bones = public_model(folder)
        with torch.no_grad():
            for name, value in theirs.named_parameters():
                if name.endswith("_scale"):
                    value.normal_(0.0, 0.5)
        ours = zoo.create_model("ggmotion", benchmark="cmu")
        ours.load_state_dict(theirs.state_dict())
        g = torch.Generator().manual_seed(1)
        history = torch.randn(64, 25, 3, 10, generator=g).cumsum(-1) * 0.02
        history = history + torch.randn(64, 25, 3, 1, generator=g) * 0.3
        target = history[..., -1:] + torch.randn(64, 25, 3, 25, generator=g).cumsum(-1) * 0.02
        losses, predictions = [], []
        for model, forward in ((theirs, theirs), (ours, ours.predict_units)):
            model.train()
            model.zero_grad()
            prediction = forward(history)
            loss = code_loss(prediction, target, torch.from_numpy(bones))
            loss.backward()
            losses.append(loss.item())
            predictions.append(prediction.detach())
        ours_grads = dict(ours.named_parameters())
        grad = max(
            (p.grad - ours_grads[n].grad).abs().max().item() for n, p in theirs.named_parameters()
        )
        print(
            f"ggmotion against the public code (long CMU model, "
            f"{sum(p.numel() for p in ours.parameters()):,} parameters, the same state dict):"
        )
        gap = (predictions[0] - predictions[1]).abs().max()
        print(
            f"  prediction: largest difference {gap:.3g} (values up to "
            f"{predictions[0].abs().max():.3g}, units of mm / 1000)"
        )
        print(f"  loss: {losses[0]:.7f} public, {losses[1]:.7f} zoo")
        print(f"  gradients: largest difference {grad:.3g}")
        times = {}
        for name, model, forward in (
            ("public", theirs, theirs),
            ("zoo", ours, ours.predict_units),
        ):
            optimizer = torch.optim.Adam(model.parameters(), lr=3e-4, weight_decay=5e-5)
            runs = []
            for _ in range(args.repeats + 1):
                started = time.perf_counter()
                optimizer.zero_grad()
                code_loss(forward(history), target, torch.from_numpy(bones)).backward()
                torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
                optimizer.step()
                runs.append(time.perf_counter() - started)
            times[name] = statistics.median(runs[1:])
        print(
            f"  training step, batch 64, {torch.get_num_threads()} thread(s): public "
            f"{times['public'] * 1e3:.0f} ms, zoo {times['zoo'] * 1e3:.0f} ms "
            f"(ratio {times['public'] / times['zoo']:.2f}x)"
        )
    finally:
        torch.Tensor.cuda = cuda
    return 0


if __name__ == "__main__":
    sys.exit(main())
