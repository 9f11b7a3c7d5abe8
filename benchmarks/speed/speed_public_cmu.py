"""Training steps of the zoo's LTD, PGBIG and MSR-GCN against their public code's, side by side.

Each public model runs from a checkout outside this repository (nothing of it is copied
here): put them in one folder, by default ``../public`` beside this repository, or name it with
``--public DIR``:

    DIR/LearnTrajDep   a checkout of wei-mao-2019/LearnTrajDep  (utils/model.py: GCN)
    DIR/PGBIG          a checkout of 705062791/PGBIG            (model/stage_4.py, utils/util.py)
    DIR/MSRGCN         a checkout of Droliven/MSRGCN            (nets/msrgcn.py, datas/dct.py)

A missing checkout is skipped with a line that says so. The public step is the body of each
code's CMU training loop as it runs on a batch its data loader has made (the DCT its loaders
compute per window is outside the step; the zoo's models take positions and compute it inside
theirs): LTD's ``main_cmu_3d.train`` (forward, inverse DCT with the matrix rebuilt per step,
mean joint distance over 35 frames, clip 1, Adam), PGBIG's ``main_cmu_3d.run_model`` (three
accumulated-average smoothings of the targets, four stages, the mean of their losses, clip
10,000, Adam) and MSR-GCN's ``CMURunner.train`` (forward on the four scales, un-normalised, the
inverse DCT, the sum of the scales' losses, Adam, no clip); ``.cuda()`` calls left out. The
zoo's step is :func:`zoo.train.step.training_step` with the registry recipe. Same batch (16 CMU
windows, 10 + 25 frames, 25 joints, in mm), same threads, float32; each step timed ``--repeats``
times, the two in turn so they share the machine's load; medians.

Run: python benchmarks/speed/speed_public_cmu.py [--public DIR] [--repeats 9] [--threads 1]
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import statistics
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch
from torch import nn

from zoo.models.dct import dct_matrix
from zoo.models.recipe import training_recipe
from zoo.models.registry import load_registry
from zoo.paths import REPO_ROOT
from zoo.train.step import make_optimizer, training_step

BATCH, T_IN, T_OUT, POINTS = 16, 10, 25, 25
FRAMES = T_IN + T_OUT


@contextmanager
def public_code(folder: Path, packages: tuple[str, ...]):
    """``folder`` first on ``sys.path`` while its modules are imported, and its top-level
    ``packages`` forgotten afterwards (the checkouts share names such as ``utils``)."""
    sys.path.insert(0, str(folder))
    try:
        yield
    finally:
        sys.path.remove(str(folder))
        for name in [m for m in sys.modules if m.split(".")[0] in packages]:
            del sys.modules[name]


def batch(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """A smooth random batch in mm: history (B, 10, 25, 3) and future (B, 25, 25, 3)."""
    g = torch.Generator().manual_seed(seed)
    start = 300 * torch.randn(BATCH, 1, POINTS, 3, generator=g)
    frames = start + 8 * torch.randn(BATCH, FRAMES, POINTS, 3, generator=g).cumsum(dim=1)
    return frames[:, :T_IN].contiguous(), frames[:, T_IN:].contiguous()


def padded_dct(history: torch.Tensor, dct_n: int) -> torch.Tensor:
    """What the public loaders hand the models: (B, 75, dct_n) DCT of the padded input."""
    padded = torch.cat([history, history[:, -1:].expand(-1, T_OUT, -1, -1)], dim=1)
    return (dct_matrix(FRAMES)[:dct_n] @ padded.reshape(BATCH, FRAMES, -1)).transpose(1, 2)


def loop_dct_matrices(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The DCT matrix and its inverse as LearnTrajDep's ``utils/data_utils.get_dct_matrix``
    builds them: a Python double loop, then a matrix inverse (its module imports ``six``, so it
    is stated here rather than imported)."""
    m = np.eye(n)
    for k in range(n):
        for i in range(n):
            w = np.sqrt(2 / n) if k else np.sqrt(1 / n)
            m[k, i] = w * np.cos(np.pi * (i + 1 / 2) * k / n)
    return m, np.linalg.inv(m)


def public_ltd(folder: Path, history, future):
    # the file alone: the package's __init__ imports its data code and that code's dependencies
    spec = importlib.util.spec_from_file_location("ltd_public_model", folder / "utils" / "model.py")
    model_module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(model_module)
    model = model_module.GCN(
        input_feature=35, hidden_feature=256, p_dropout=0.5, num_stage=12, node_n=75
    )
    optimizer = torch.optim.Adam(model.parameters(), lr=5e-4)
    inputs = padded_dct(history, 35)
    all_seq = torch.cat([history, future], dim=1).reshape(BATCH, FRAMES, -1)

    def step():
        outputs = model(inputs)
        _, idct_m = loop_dct_matrices(FRAMES)  # rebuilt every step, as the code does
        idct_m = torch.from_numpy(idct_m).float()
        outputs_t = outputs.view(-1, 35).transpose(0, 1)
        p3d = torch.matmul(idct_m[:, :35], outputs_t).transpose(0, 1).contiguous()
        p3d = p3d.view(-1, 75, FRAMES).transpose(1, 2).contiguous().view(-1, 3)
        loss = torch.mean(torch.norm(all_seq.reshape(-1, 3) - p3d, 2, 1))
        optimizer.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(model.parameters(), max_norm=1)
        optimizer.step()

    return model, step


def public_pgbig(folder: Path, history, future):
    with public_code(folder, ("utils", "model")):
        stage_4 = importlib.import_module("model.stage_4")
    opt = SimpleNamespace(
        kernel_size=10, d_model=16, dct_n=35, in_features=75, num_stage=12, drop_out=0.3,
        input_n=T_IN, output_n=T_OUT, cuda_idx="cpu", encoder_n=6, decoder_n=6,
    )  # fmt: skip
    model = stage_4.MultiStageModel(opt=opt)
    optimizer = torch.optim.Adam(model.parameters(), lr=5e-3)
    seq = torch.cat([history, future], dim=1).reshape(BATCH, FRAMES, -1)

    def smooth(src):  # main_cmu_3d.smooth: future frame t -> mean of future frames 1..t
        data = src[:, -FRAMES:].clone()
        out = data.clone()
        for i in range(10, FRAMES):
            out[:, i] = torch.mean(data[:, 10 : i + 1], dim=1)
        return out

    def step():
        s1 = smooth(seq).clone()
        s2 = smooth(s1).clone()
        s3 = smooth(s2).clone()
        targets = [t.reshape(BATCH, FRAMES, POINTS, 3) for t in (seq, s1, s2, s3)]
        outs = model(seq.clone(), input_n=T_IN, output_n=T_OUT, itera=1)
        losses = [
            torch.mean(torch.norm(o.reshape(BATCH, FRAMES, POINTS, 3) - t, dim=3))
            for o, t in zip(outs, targets)
        ]
        loss = sum(losses) / 4
        optimizer.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(list(model.parameters()), max_norm=10000)
        optimizer.step()

    return model, step


def public_msrgcn(folder: Path, history, future):
    from zoo.models.msrgcn import MSRGCN

    with public_code(folder, ("nets", "datas")):
        nets = importlib.import_module("nets.msrgcn")
    model = nets.MSRGCN(0.1, 0.2, 25, input_feature=35)
    optimizer = torch.optim.Adam(model.parameters(), lr=2e-4)
    groups = load_registry().get("msrgcn").hparams["groups"]
    zoo_scales = MSRGCN(T_IN, T_OUT, POINTS, groups).scales  # the same means of groups
    frames = torch.cat([history, future], dim=1)
    padded = torch.cat([history, history[:, -1:].expand(-1, T_OUT, -1, -1)], dim=1)
    low, high = -7840.2, 5227.3  # the code's range on CMU's training windows (the card)
    keys = ("p22", "p12", "p7", "p4")
    dct = dct_matrix(FRAMES)
    inputs = {
        k: ((dct @ s.reshape(BATCH, FRAMES, -1)).transpose(1, 2) - low) / (high - low) * 2 - 1
        for k, s in zip(keys, zoo_scales(padded))
    }
    gts = {
        k: s.reshape(BATCH, FRAMES, -1).transpose(1, 2) for k, s in zip(keys, zoo_scales(frames))
    }
    idct = dct.T.contiguous()

    def loss_of(gt, out):  # run/cmu_runner.L2NormLoss_train
        gt = gt.reshape(BATCH, -1, 3, FRAMES).permute(0, 3, 1, 2)
        out = out.reshape(BATCH, -1, 3, FRAMES).permute(0, 3, 1, 2)
        return torch.mean(torch.norm(gt - out, 2, dim=-1))

    def step():
        outputs = model(inputs)
        losses = None
        for k in outputs:
            o = (outputs[k] + 1) / 2 * (high - low) + low
            o = torch.matmul(idct[:, :35], o.transpose(1, 2)).transpose(1, 2)  # reverse_dct_torch
            current = loss_of(gts[k], o)
            losses = current if losses is None else losses + current
        optimizer.zero_grad()
        losses.backward()
        optimizer.step()

    return model, step


def msrgcn_names() -> dict[str, str]:
    """The zoo's MSR-GCN parameter and buffer name for each of the public code's."""
    names: dict[str, str] = {}

    def conv(public: str, zoo: str) -> None:
        names.update({f"{public}.weight": f"{zoo}.weight", f"{public}.bias": f"{zoo}.bias"})
        names[f"{public}.att"] = f"{zoo}.adjacency"

    def norm(public: str, zoo: str) -> None:
        for key in ("weight", "bias", "running_mean", "running_var", "num_batches_tracked"):
            names[f"{public}.{key}"] = f"{zoo}.{key}"

    def block(public: str, zoo: str) -> None:
        conv(f"{public}.gc1", f"{zoo}.first.conv")
        norm(f"{public}.bn1", f"{zoo}.first.act.norm")
        conv(f"{public}.gc2", f"{zoo}.second.conv")
        norm(f"{public}.bn2", f"{zoo}.second.act.norm")

    def linear(public: str, zoo: str) -> None:
        names[f"{public}.linear.weight"] = f"{zoo}.linear.weight"
        names[f"{public}.linear.bias"] = f"{zoo}.linear.bias"
        norm(f"{public}.bn", f"{zoo}.act.norm")

    scale = ("first", "second", "third", "fourth")
    for s, n in enumerate(scale):
        conv(f"{n}_enhance.gcn", f"enter.{s}.conv")
        norm(f"{n}_enhance.bn1d", f"enter.{s}.act.norm")
        conv(f"{n}_out.gcn", f"readout.{s}")
        for i in range(3):
            block(f"{n}_left.{i}", f"encode.{s}.blocks.{i}")
            block(f"{n}_right.{i}", f"decode.{s}.blocks.{i}")
        for i in range(6 if s == 0 else 1):
            block(f"{n}_extra.{i}", f"heads.{s}.blocks.{i}")
        if s < 3:
            linear(f"{n}_down.0", f"down.{s}")
            linear(f"{n}_right_crop.0", f"merge.{s}")
            linear(f"{scale[s + 1]}_up.0", f"up.{s}.0")
            linear(f"{scale[s + 1]}_up.1", f"up.{s}.1")
    return names


def msrgcn_difference(public_model, history) -> float:
    """The largest difference (mm) between the public model and the zoo's carrying its weights,
    in eval mode, over every scale's 35 frames: the two compute the same function."""
    from zoo.models.msrgcn import MSRGCN

    groups = load_registry().get("msrgcn").hparams["groups"]
    ours = MSRGCN(T_IN, T_OUT, POINTS, groups).eval()
    names = msrgcn_names()
    state = ours.state_dict()
    state.update({names[k]: v for k, v in public_model.state_dict().items()})
    ours.load_state_dict(state)
    ours.low.fill_(-7840.2)
    ours.high.fill_(5227.3)
    public_model.eval()
    padded = torch.cat([history, history[:, -1:].expand(-1, T_OUT, -1, -1)], dim=1)
    dct = dct_matrix(FRAMES)
    span = float(ours.high - ours.low)
    keys = ("p22", "p12", "p7", "p4")
    inputs = {
        k: ((dct @ s.reshape(BATCH, FRAMES, -1)).transpose(1, 2) - ours.low) / span * 2 - 1
        for k, s in zip(keys, ours.scales(padded))
    }
    with torch.no_grad():
        public_out, zoo_out = public_model(inputs), ours.reconstruct(history)
    public_model.train()
    worst = 0.0
    for k, frames in zip(keys, zoo_out):
        coefficients = (public_out[k] + 1) / 2 * span + float(ours.low)
        public_frames = (dct.T @ coefficients.transpose(1, 2)).reshape(frames.shape)
        worst = max(worst, float((public_frames - frames).abs().max()))
    return worst


def zoo_step(name: str, history, future):
    registry = load_registry()
    entry = registry.get(name)
    # float32 as the public code runs (a recipe's precision: auto would be bfloat16 on some CPUs)
    recipe = training_recipe(entry.train, {"precision": "float32"})
    model = registry.create_model(name, input_frames=T_IN, output_frames=T_OUT, num_points=POINTS)
    optimizer = make_optimizer(model, recipe, "cpu")
    if name == "msrgcn":
        model.low.fill_(-7884.2)  # the zoo's bound on the same data (the card)
        model.high.fill_(5727.6)
    model.train()

    def step():
        training_step(model.training_loss, model, optimizer, history, future, recipe, "cpu")

    return model, step


def median_ms(step, repeats: int) -> list[float]:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        step()
        times.append(1000 * (time.perf_counter() - started))
    return times


PUBLIC = {
    "ltd": ("LearnTrajDep", public_ltd),
    "pgbig": ("PGBIG", public_pgbig),
    "msrgcn": ("MSRGCN", public_msrgcn),
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--public", type=Path, default=REPO_ROOT.parent / "public")
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--model", action="append", choices=sorted(PUBLIC), default=[])
    parser.add_argument(
        "--profile", action="store_true", help="also where the zoo's step spends its time"
    )
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    history, future = batch()
    print(f"threads {args.threads}, batch {BATCH}, float32, medians of {args.repeats} steps")
    for name in args.model or sorted(PUBLIC):
        folder_name, make_public = PUBLIC[name]
        folder = args.public / folder_name
        if not folder.is_dir():
            print(f"{name}: no public checkout at {folder} (see this script's docstring); skipped")
            continue
        public_model, public = make_public(folder, history, future)
        ours_model, ours = zoo_step(name, history, future)
        counts = [sum(p.numel() for p in m.parameters()) for m in (public_model, ours_model)]
        public(), ours()  # warm-up
        t_public, t_ours = [], []
        for _ in range(args.repeats):  # in turn, so both see the same load
            t_public += median_ms(public, 1)
            t_ours += median_ms(ours, 1)
        a, b = statistics.median(t_public), statistics.median(t_ours)
        print(
            f"{name}: public {a:.1f} ms/step ({counts[0]:,} parameters), zoo {b:.1f} ms/step "
            f"({counts[1]:,}): the zoo's step takes {b / a:.2f}x the public code's"
        )
        if name == "msrgcn":
            print(
                f"msrgcn: the public model and the zoo's carrying its weights (eval mode) differ "
                f"by at most {msrgcn_difference(public_model, history):.3g} mm over every scale"
            )
        if args.profile:
            from torch.profiler import ProfilerActivity, profile

            with profile(activities=[ProfilerActivity.CPU]) as prof:
                for _ in range(3):
                    ours()
            print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=8))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
