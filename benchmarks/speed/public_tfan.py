"""TFAN against its public code (Deante-dx/TFAN) with the authors' CMU weights: the same
predictions, the same parameter count, the same training losses and gradients, and the forward
and the training steps of each timed side by side.

The public model runs from a checkout outside this repository (nothing of it is copied here):
``DIR/TFAN``, with DIR ``../public`` beside this repository by default, or ``--public DIR``. Its
``models/Predictor.py`` needs ``einops``, which the zoo does not: install it apart (``pip
install --target DEPS einops``) and name that folder with ``--deps DEPS``. The public side is
the body of the code's CMU test loop (``exp/cmu/fusion/test.py``, ``regress_pred``: both
predictors on the DCT of 50 frames, the gate, ``fusion_C``, 10 frames a call, rolled out three
times), ``.cuda()`` calls left out. Its three state dicts
(``checkpoints/cmu/model_{position,bone,fusion}.pth``) load into the public models and, renamed
(``position.``, ``bone.``, ``fc.`` to ``gate.``), into the zoo's. Both get the 50-frame
histories of the ``cmu50`` ``ltd8`` windows (the zoo's CMU loader, in mm; the public side in
metres as its loader gives them); the script prints the largest absolute and relative
differences of the predictions in mm, the largest gap per action between the authors' test
metric on the public predictions and the zoo's row (``used25``, frame averaging), and each
side's median milliseconds of one forward of a batch, the two timed in turn so they share the
machine's load.

Training: the public side is the body of the code's ``train_step`` of each stage
(``exp/cmu/position``, ``exp/cmu/bone``: a stream's next 10 frames, the mean point distance plus
that of the frame-to-frame changes; ``exp/cmu/fusion``: the same on the fused frames, both
streams detached), the zoo's is ``training_loss`` in its two phases (both streams in one loss,
then the gate). On one batch of 64 ``cmu50`` windows the script prints the largest difference of
the losses and of the gradients, and each side's median milliseconds of an optimizer step (Adam,
the code's learning rate and weight decay): the zoo's streams step against the public position
step plus the public bone step (the code trains them one after the other), the zoo's gate step
against the public fusion step.

Run: python benchmarks/speed/public_tfan.py [--public DIR] [--deps DEPS] [--repeats 9]
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

import zoo
from zoo.data.windows import gather_windows, window_sampler
from zoo.paths import REPO_ROOT
from zoo.protocol.benchmark import get_benchmark

STEP, T_IN, T_OUT = 10, 50, 25


def _module(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def public_model(folder: Path):
    """The public predictors, gate and fusion function, holding the authors' CMU weights."""
    predictor = _module(folder / "models" / "Predictor.py", "tfan_public_predictor")
    gate = _module(folder / "models" / "FusionModel.py", "tfan_public_gate")
    fusion = _module(folder / "exp" / "cmu" / "fusion" / "Fusion.py", "tfan_public_fusion")
    weights = folder / "checkpoints" / "cmu"
    position, bone = predictor.Predictor(48, 50, 75, 25), predictor.Predictor(48, 50, 75, 25)
    fuse = gate.FusionModel(10, 75)
    for model, file in ((position, "position"), (bone, "bone"), (fuse, "fusion")):
        state = torch.load(weights / f"model_{file}.pth", map_location="cpu", weights_only=True)
        model.load_state_dict(state, strict=True)
        model.eval()
    return position, bone, fuse, fusion.fusion_C, weights


def public_dct(n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The code's ``get_dct_matrix``: a double loop, then a matrix inverse, cast to float32."""
    m = np.eye(n)
    for k in range(n):
        for i in range(n):
            w = np.sqrt(2 / n) if k else np.sqrt(1 / n)
            m[k, i] = w * np.cos(np.pi * (i + 1 / 2) * k / n)
    return torch.tensor(m).float()[None], torch.tensor(np.linalg.inv(m)).float()[None]


START = [0, 1, 2, 4, 5, 6, 8, 9, 10, 11, 9, 13, 14, 15, 16, 15, 9, 19, 20, 21, 22, 21]
END = [1, 2, 3, 5, 6, 7, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24]


def public_predict(parts, history_m: torch.Tensor) -> torch.Tensor:
    """``regress_pred``'s body on one batch ``(B, 50, 25, 3)`` in metres: ``(B, 25, 25, 3)``."""
    position, bone, fuse, fusion_c, _ = parts
    dct_m, idct_m = public_dct(T_IN)
    b = history_m.shape[0]
    bones = history_m[:, :, END] - history_m[:, :, START]
    bone_input = torch.cat([history_m[:, :, [0, 4, 8]], bones], dim=2).reshape(b, T_IN, -1)
    motion_input = history_m.reshape(b, T_IN, -1)
    outputs = []
    for _ in range(T_OUT // STEP + 1):
        position_pred = position(torch.matmul(dct_m, motion_input))
        bone_pred = bone(torch.matmul(dct_m, bone_input))
        position_pred = torch.matmul(idct_m, position_pred)[:, :STEP]
        bone_pred = torch.matmul(idct_m, bone_pred)[:, :STEP] + bone_input[:, -1:]
        position_pred = position_pred + motion_input[:, -1:].repeat(1, STEP, 1)
        s = fuse(bone_pred, position_pred)
        output = fusion_c(bone_pred, position_pred, s).reshape(b, STEP, 25, 3)
        bone_out = torch.cat([output[:, :, [0, 4, 8]], output[:, :, END] - output[:, :, START]], 2)
        outputs.append(output.reshape(b, STEP, -1))
        motion_input = torch.cat([motion_input[:, STEP:], outputs[-1]], dim=1)
        bone_input = torch.cat([bone_input[:, STEP:], bone_out.reshape(b, STEP, -1)], dim=1)
    return torch.cat(outputs, dim=1)[:, :T_OUT].reshape(b, T_OUT, 25, 3)


def zoo_model(weights: Path) -> torch.nn.Module:
    model = zoo.create_model("tfan", benchmark="cmu50")
    state = {}
    for file, prefix in (("position", "position."), ("bone", "bone."), ("fusion", "gate.")):
        loaded = torch.load(weights / f"model_{file}.pth", map_location="cpu", weights_only=True)
        state.update(
            {
                prefix + k.removeprefix("fc.") if file == "fusion" else prefix + k: v
                for k, v in loaded.items()
            }
        )
    model.load_state_dict(state, strict=True)
    return model.eval()


def cmu50_windows(sampler: str = "ltd8") -> tuple[torch.Tensor, torch.Tensor, list[str]]:
    """Every ``cmu50`` window of ``sampler`` on the 25 predicted joints, in mm: its 50 observed
    frames, its 25 future ones, and its action."""
    bench = get_benchmark("cmu50")
    data = bench.load()
    positions = [s.positions for s in data.sequences]
    index = window_sampler(sampler, [len(p) for p in positions], T_IN, T_OUT)
    windows = gather_windows(positions, index, T_IN + T_OUT)[:, :, list(bench.skeleton.used)]
    windows = torch.from_numpy(windows).float()
    actions = [data.sequences[i].action for i in index[:, 0]]
    return windows[:, :T_IN], windows[:, T_IN:], actions


def per_action_gaps(ours, theirs_mm, future, actions) -> float:
    """The largest gap, over actions and the test script's horizons, between the authors' test
    metric on the public predictions (mean over windows of the mean joint distance, 25 joints,
    mm) and the zoo's row of the same windows (``used25``, frame averaging)."""
    frame = zoo.evaluate(ours, "cmu50", label="tfan", sampler="ltd8").frame
    rows = frame[(frame.joints == "used25") & (frame.averaging == "frame")]
    largest = 0.0
    for action in sorted(set(actions)):
        mine = [i for i, a in enumerate(actions) if a == action]
        error = (theirs_mm[mine] - future[mine]).norm(dim=3).mean(dim=2).mean(dim=0)
        for t in (2, 4, 8, 10, 14, 18, 22, 25):  # the test script's results_keys
            row = rows[(rows.action == action) & (rows.frame == t)]["value"].item()
            largest = max(largest, abs(row - error[t - 1].item()))
    return largest


def _distance(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The code's loss: ``rloss + dloss`` of its train steps, on ``(B, 10, 75)`` in metres."""
    b = pred.shape[0]
    pred, target = pred.reshape(b, STEP, 25, 3), target.reshape(b, STEP, 25, 3)
    moved = (pred[:, 1:] - pred[:, :-1]) - (target[:, 1:] - target[:, :-1])
    return torch.mean(torch.norm((pred - target).reshape(-1, 3), 2, 1)) + torch.mean(
        torch.norm(moved.reshape(-1, 3), 2, 1)
    )


def _bones(frames: torch.Tensor) -> torch.Tensor:
    """``(B, T, 25, 3)`` to the code's bone input: the roots, then the 22 bone vectors."""
    bones = torch.cat([frames[:, :, [0, 4, 8]], frames[:, :, END] - frames[:, :, START]], dim=2)
    return bones.reshape(frames.shape[0], frames.shape[1], -1)


def public_stream_loss(predictor, inputs: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """A stream's ``train_step`` loss (``exp/cmu/position`` and ``exp/cmu/bone``): the inverse
    DCT of its prediction, its first 10 frames plus the last observed one, against ``target``."""
    dct_m, idct_m = public_dct(T_IN)
    pred = torch.matmul(idct_m, predictor(torch.matmul(dct_m, inputs)))[:, :STEP]
    return _distance(pred + inputs[:, -1:], target)


def public_fusion_loss(parts, history_m, target_m) -> torch.Tensor:
    """``exp/cmu/fusion``'s ``train_step`` loss: both streams' predictions detached, the gate,
    ``fusion_C``."""
    position, bone, fuse, fusion_c, _ = parts
    dct_m, idct_m = public_dct(T_IN)
    b = history_m.shape[0]
    motion, bones = history_m.reshape(b, T_IN, -1), _bones(history_m)
    p = torch.matmul(idct_m, position(torch.matmul(dct_m, motion)))[:, :STEP] + motion[:, -1:]
    q = torch.matmul(idct_m, bone(torch.matmul(dct_m, bones)))[:, :STEP] + bones[:, -1:]
    p, q = p.detach(), q.detach()
    return _distance(fusion_c(q, p, fuse(q, p)), target_m.reshape(b, STEP, -1))


def training_checks(parts, ours, history, future, repeats: int) -> None:
    """Losses and gradients of both sides on one batch, then their optimizer steps timed."""
    position, bone, fuse = parts[:3]
    h, target = history / 1000, future[:, :STEP] / 1000
    b = h.shape[0]
    for m in (position, bone, fuse, ours):
        m.train()
    public_streams = {
        "position": lambda: public_stream_loss(position, h.reshape(b, T_IN, -1), target),
        "bone": lambda: public_stream_loss(bone, _bones(h), _bones(target)),
    }
    ours.start_epoch(0, frames=None)
    zoo_streams = ours.training_loss(history, future)
    theirs = [public_streams["position"](), public_streams["bone"]()]
    ours.zero_grad(set_to_none=True)
    zoo_streams.backward()
    for loss in theirs:
        loss.backward()
    grad_gap = max(
        (dict(ours.named_parameters())[f"{prefix}.{n}"].grad - p.grad).abs().max().item()
        for prefix, model in (("position", position), ("bone", bone))
        for n, p in model.named_parameters()
    )
    largest = max(p.grad.abs().max().item() for m in (position, bone) for p in m.parameters())
    print(
        f"streams' loss: zoo {zoo_streams.item():.7f}, public position + bone "
        f"{sum(t.item() for t in theirs):.7f}; largest gradient difference {grad_gap:.2g} "
        f"(largest gradient {largest:.2g})"
    )
    ours.start_epoch(ours.streams_epochs, frames=None)
    zoo_gate = ours.training_loss(history, future)
    public_gate = public_fusion_loss(parts, h, target)
    ours.zero_grad(set_to_none=True)
    zoo_gate.backward()
    public_gate.backward()
    gate_gap = max(
        (ours.gate.weight.grad - fuse.fc.weight.grad).abs().max().item(),
        (ours.gate.bias.grad - fuse.fc.bias.grad).abs().max().item(),
    )
    print(
        f"gate's loss: zoo {zoo_gate.item():.7f}, public {public_gate.item():.7f}; largest "
        f"gradient difference {gate_gap:.2g} (largest gradient "
        f"{fuse.fc.weight.grad.abs().max().item():.2g})"
    )

    def stepper(model, loss_fn):
        optimizer = torch.optim.Adam(model.parameters(), lr=3e-4, weight_decay=1e-4)

        def step():
            loss = loss_fn()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()

        return step

    public_steps = {
        "position": stepper(position, public_streams["position"]),
        "bone": stepper(bone, public_streams["bone"]),
        "fusion": stepper(fuse, lambda: public_fusion_loss(parts, h, target)),
    }
    zoo_step = stepper(ours, lambda: ours.training_loss(history, future))
    for phase, epoch in (("streams", 0), ("gate", ours.streams_epochs)):
        public_ms, zoo_ms = [], []
        for _ in range(repeats):  # in turn, so both see the same load
            if phase == "streams":
                public_ms.append(
                    _median_ms(public_steps["position"], 1) + _median_ms(public_steps["bone"], 1)
                )
            else:
                public_ms.append(_median_ms(public_steps["fusion"], 1))
            ours.start_epoch(epoch, frames=None)
            zoo_ms.append(_median_ms(zoo_step, 1))
        p, z = statistics.median(public_ms), statistics.median(zoo_ms)
        what = "position + bone steps" if phase == "streams" else "fusion step"
        print(
            f"training step, {phase}, batch {b}, {torch.get_num_threads()} thread(s): zoo "
            f"{z:.1f} ms, public {what} {p:.1f} ms, zoo / public {z / p:.2f}"
        )


def _median_ms(call, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        began = time.perf_counter()
        call()
        times.append(1000 * (time.perf_counter() - began))
    return statistics.median(times)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--public", type=Path, default=REPO_ROOT.parent / "public")
    parser.add_argument("--deps", type=Path, default=None, help="folder holding einops")
    parser.add_argument("--repeats", type=int, default=9)
    args = parser.parse_args(argv)
    checkout = args.public / "TFAN"
    if not (checkout / "models" / "Predictor.py").is_file():
        print(f"no public checkout at {checkout} (a clone of Deante-dx/TFAN): nothing compared")
        return 0
    if args.deps is not None:
        sys.path.insert(0, str(args.deps))
    parts = public_model(checkout)
    ours = zoo_model(parts[-1])
    history, future, actions = cmu50_windows()
    with torch.no_grad():
        theirs = public_predict(parts, history / 1000) * 1000
        mine = ours(history)
    diff = (mine - theirs).abs()
    public_count = sum(p.numel() for m in parts[:3] for p in m.parameters())
    print(f"windows: {len(history)} (cmu50 ltd8, 50 observed frames, 25 joints)")
    print(f"parameters: zoo {sum(p.numel() for p in ours.parameters()):,}, public {public_count:,}")
    print(
        f"prediction: largest absolute difference {diff.max().item():.3g} mm, largest relative "
        f"{(diff / theirs.abs().clamp_min(1.0)).max().item():.3g} (of |public| >= 1 mm), "
        f"mean |public| {theirs.abs().mean().item():.1f} mm"
    )
    print(
        f"per action, at the test script's 8 horizons: the authors' test metric on the public "
        f"predictions against the zoo's row, largest gap "
        f"{per_action_gaps(ours, theirs, future, actions):.3g} mm"
    )
    batch = history[:64]
    public_ms, zoo_ms = [], []
    with torch.no_grad():
        for _ in range(args.repeats):  # in turn, so both see the same load
            public_ms.append(_median_ms(lambda: public_predict(parts, batch / 1000), 1))
            zoo_ms.append(_median_ms(lambda: ours(batch), 1))
    p, z = statistics.median(public_ms), statistics.median(zoo_ms)
    print(
        f"forward of 64 windows, {torch.get_num_threads()} thread(s): zoo {z:.1f} ms, "
        f"public {p:.1f} ms, zoo / public {z / p:.2f}"
    )
    history, future, _ = cmu50_windows("all")
    training_checks(parts, ours, history[:64], future[:64], args.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
