"""MSR-GCN's first training steps: the zoo's model and step beside the public code's, from the
same initial weights, on the same CMU training batches.

The public model (a Droliven/MSRGCN checkout, found as ``speed_public_cmu.py`` finds it) gets the
zoo's seed-0 initial weights; both train with Adam at the recipe's rate on the zoo's training
windows (``val_split`` of the registry recipe) in one fixed order, with the same input range.
Every ``--every`` steps each side's mean training loss since the last line is printed, with
its MPJPE (mean over the 25 predicted frames, and at 1000 ms) on a fixed probe of
validation windows in eval mode, beside repeat-last's, and the mean size of its residual (the
network's output minus its input, finest scale, in the [-1, 1] units of the input range). The
two differ only in dropout's masks and float rounding: if the zoo reproduces the code, the
columns move together.

Run: python benchmarks/speed/public_msrgcn_training.py [--public DIR] [--steps 2000]
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import speed_public_cmu as public_cmu  # noqa: E402

from zoo.data.windows import gather_windows  # noqa: E402
from zoo.models.dct import dct_matrix  # noqa: E402
from zoo.models.recipe import training_recipe  # noqa: E402
from zoo.models.registry import load_registry  # noqa: E402
from zoo.paths import REPO_ROOT  # noqa: E402
from zoo.protocol.benchmark import get_benchmark  # noqa: E402
from zoo.train.split import split_train_val, usable_windows  # noqa: E402
from zoo.train.step import make_optimizer, training_step  # noqa: E402

KEYS = ("p22", "p12", "p7", "p4")


def windows(bench, recipe, data_root, probe: int):
    """The training windows ``(positions, index)`` and a probe of ``probe`` validation windows
    ``(B, T, 25, 3)``, spread evenly over them."""
    dataset = bench.load(data_root, split=bench.train_split)
    length = bench.input_frames + bench.output_frames
    train, val = split_train_val(dataset, recipe.val_fraction, length, rule=recipe.val_split)
    t_in, t_out = bench.input_frames, bench.output_frames
    train_pos, train_index = usable_windows(train, length, "all", t_in, t_out)
    val_pos, val_index = usable_windows(val, length, "all", t_in, t_out)
    rows = np.linspace(0, len(val_index) - 1, probe).astype(int)
    used = list(bench.skeleton.used)
    probe_windows = gather_windows(val_pos, val_index[rows], length)[:, :, used]
    return train_pos, train_index, used, torch.from_numpy(np.ascontiguousarray(probe_windows))


class PublicSide:
    """The public model, fed as its CMU runner feeds it, trained with its loss (the sum over
    scales of the mean point distance over all frames) and Adam."""

    def __init__(self, folder: Path, zoo_model, lr: float) -> None:
        with public_cmu.public_code(folder, ("nets", "datas")):
            nets = importlib.import_module("nets.msrgcn")
        self.model = nets.MSRGCN(0.1, 0.2, 25, input_feature=35)
        names = public_cmu.msrgcn_names()
        state = zoo_model.state_dict()
        self.model.load_state_dict({k: state[names[k]].clone() for k in self.model.state_dict()})
        self.optimizer = torch.optim.Adam(self.model.parameters(), lr=lr)
        self.zoo = zoo_model  # for the scales and the range only
        frames = zoo_model.input_frames + zoo_model.output_frames
        self.dct = dct_matrix(frames)

    def io(self, history, future):
        z, batch = self.zoo, len(history)
        frames = torch.cat([history, future], 1)
        padded = torch.cat([history, history[:, -1:].expand(-1, z.output_frames, -1, -1)], 1)
        low, high = float(z.low), float(z.high)
        inputs = {
            k: ((self.dct @ s.reshape(batch, len(self.dct), -1)).transpose(1, 2) - low)
            / (high - low) * 2 - 1
            for k, s in zip(KEYS, z.scales(padded))
        }  # fmt: skip
        targets = {
            k: s.reshape(batch, len(self.dct), -1).transpose(1, 2)
            for k, s in zip(KEYS, z.scales(frames))
        }
        return inputs, targets

    def frames(self, outputs):
        low, high = float(self.zoo.low), float(self.zoo.high)
        return {
            k: (self.dct.T @ ((o + 1) / 2 * (high - low) + low).transpose(1, 2)).transpose(1, 2)
            for k, o in outputs.items()
        }

    def step(self, history, future) -> float:
        inputs, targets = self.io(history, future)
        outputs = self.frames(self.model(inputs))
        batch, length = len(history), len(self.dct)
        loss = 0
        for k, out in outputs.items():
            gt = targets[k].reshape(batch, -1, 3, length).permute(0, 3, 1, 2)
            out = out.reshape(batch, -1, 3, length).permute(0, 3, 1, 2)
            loss = loss + torch.mean(torch.norm(gt - out, 2, dim=-1))
        self.optimizer.zero_grad()
        loss.backward()
        self.optimizer.step()
        return float(loss)

    @torch.no_grad()
    def probe(self, history, future):
        self.model.eval()
        inputs, _ = self.io(history, future)
        out = self.model(inputs)
        residual = float((out["p22"] - inputs["p22"]).abs().mean())
        pred = self.frames({"p22": out["p22"]})["p22"]
        pred = pred.reshape(len(history), -1, 25, 3)[:, history.shape[1] :]
        self.model.train()
        return torch.linalg.vector_norm(pred - future, dim=-1).mean(dim=(0, 2)), residual


@torch.no_grad()
def probe_zoo(model, history, future):
    model.eval()
    frames = model.reconstruct(history)[0]
    padded = torch.cat([history, history[:, -1:].expand(-1, model.output_frames, -1, -1)], 1)
    dct = dct_matrix(frames.shape[1])
    inputs = model._normalised(model._coefficients(padded))
    coefficients = model._normalised(
        (dct[: inputs.shape[2]] @ frames.reshape(len(frames), frames.shape[1], -1)).transpose(1, 2)
    )
    model.train()
    error = torch.linalg.vector_norm(frames[:, history.shape[1] :] - future, dim=-1)
    return error.mean(dim=(0, 2)), float((coefficients - inputs).abs().mean())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--public", type=Path, default=REPO_ROOT.parent / "public")
    parser.add_argument("--data-root", help="CMU folder (default: the benchmark's)")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--every", type=int, default=100)
    parser.add_argument("--probe", type=int, default=256, help="validation windows probed")
    parser.add_argument("--low", type=float, default=-7884.1851, help="input range (the card)")
    parser.add_argument("--high", type=float, default=5727.6265)
    parser.add_argument("--out", type=Path, help="also write the lines as JSON here")
    args = parser.parse_args(argv)
    folder = args.public / "MSRGCN"
    if not folder.is_dir():
        print(f"msrgcn: no public checkout at {folder} (see speed_public_cmu.py); skipped")
        return 0
    torch.set_num_threads(1)
    bench, registry = get_benchmark("cmu"), load_registry()
    entry = registry.get("msrgcn")
    # float32 as the public code trains (precision: auto would be bfloat16 on some CPUs)
    recipe = training_recipe(
        {"val_split": bench.val_split, **entry.train}, {"precision": "float32"}
    )
    train_pos, train_index, used, probe = windows(bench, recipe, args.data_root, args.probe)
    history, future = probe[:, : bench.input_frames], probe[:, bench.input_frames :]
    repeat = torch.linalg.vector_norm(future - history[:, -1:], dim=-1).mean(dim=(0, 2))
    torch.manual_seed(0)
    hparams = registry.model_args(
        "msrgcn",
        input_frames=bench.input_frames,
        output_frames=bench.output_frames,
        num_points=len(used),
    )
    zoo_model = registry.create_model("msrgcn", **hparams)
    zoo_model.low.fill_(args.low)
    zoo_model.high.fill_(args.high)
    optimizer = make_optimizer(zoo_model, recipe, "cpu")
    public = PublicSide(folder, zoo_model, recipe.lr)
    order = torch.randperm(len(train_index), generator=torch.Generator().manual_seed(0))
    batch, length = recipe.batch_size, bench.input_frames + bench.output_frames
    print(
        f"msrgcn: {len(train_index)} training windows, batch {batch}, lr {recipe.lr:g}, "
        f"probe {args.probe} validation windows; repeat-last there: mean {float(repeat.mean()):.1f}"
        f" mm, 1000 ms {float(repeat[-1]):.1f} mm"
    )
    print("step | loss zoo | loss code | MPJPE zoo | MPJPE code | 1000 ms zoo | 1000 ms code |"
          " residual zoo | residual code | s")  # fmt: skip
    lines, sums, started = [], [0.0, 0.0], time.perf_counter()
    for step in range(args.steps):
        first = (step * batch) % (len(order) - batch)
        rows = order[first : first + batch].numpy()
        w = gather_windows(train_pos, train_index[rows], length)[:, :, used]
        w = torch.from_numpy(np.ascontiguousarray(w))
        h, f = w[:, : bench.input_frames], w[:, bench.input_frames :]
        sums[0] += training_step(
            zoo_model.training_loss, zoo_model, optimizer, h, f, recipe, "cpu"
        ).item()
        sums[1] += public.step(h, f)
        if (step + 1) % args.every:
            continue
        (ours, ours_residual), (theirs, theirs_residual) = (
            probe_zoo(zoo_model, history, future),
            public.probe(history, future),
        )
        line = {
            "step": step + 1,
            "loss": [sums[0] / args.every, sums[1] / args.every],
            "mpjpe": [float(ours.mean()), float(theirs.mean())],
            "mpjpe_1000ms": [float(ours[-1]), float(theirs[-1])],
            "residual": [ours_residual, theirs_residual],
            "seconds": round(time.perf_counter() - started),
        }
        lines.append(line)
        sums = [0.0, 0.0]
        print(
            f"{line['step']} | {line['loss'][0]:.0f} | {line['loss'][1]:.0f} | "
            f"{line['mpjpe'][0]:.1f} | {line['mpjpe'][1]:.1f} | {line['mpjpe_1000ms'][0]:.1f} | "
            f"{line['mpjpe_1000ms'][1]:.1f} | {line['residual'][0]:.4f} | "
            f"{line['residual'][1]:.4f} | {line['seconds']}",
            flush=True,
        )
    if args.out:
        args.out.write_text(json.dumps(lines, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
