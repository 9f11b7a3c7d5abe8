"""Does a run resumed from its compact paused state train as one resumed from its full state?

Run from the repository root, on a run folder that ``zoo train`` wrote::

    python benchmarks/training/paused_state.py checkpoints/cmu/spgsn [--epochs 2] [--max-batches N]

It prints the sizes of the full state (``last.pt`` + ``best.pt`` as training writes them) and of
the paused state (``zoo weights pause``: float16 weights, Adam moments in 8 bits and bfloat16),
then resumes the run three times for ``--epochs`` epochs, on the same seed and batches:

- from the full state (the reference);
- from the paused state;
- from the full state with the dropout generator drawn anew (the training's own noise: the
  same weights, moments, batches and schedule, other dropout masks).

and prints each resumed epoch's validation MPJPE. The paused state resumes "within noise" when
its distance from the reference is no larger than the noise run's.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path

import torch

from zoo.hub.checkpoints import compact_payload, read_checkpoint, save_checkpoint
from zoo.train.loop import train
from zoo.train.options import RunOptions


def _sizes(folder: Path) -> dict[str, int]:
    return {p.name: p.stat().st_size for p in sorted(folder.glob("*.pt"))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a run folder holding last.pt and best.pt")
    parser.add_argument("--epochs", type=int, default=2, help="epochs each resume trains")
    parser.add_argument("--max-batches", type=int, help="cap batches per epoch (quick runs)")
    parser.add_argument("--noise-seed", type=int, default=1, help="the noise run's dropout seed")
    args = parser.parse_args()

    last = read_checkpoint(args.run / "last.pt")
    best = read_checkpoint(args.run / "best.pt")
    model, benchmark = last["model"], last["protocol"]["benchmark"]
    done = last["epoch"] + 1
    work = Path(tempfile.mkdtemp(prefix="paused_state."))
    folders = {name: work / name for name in ("full", "paused", "noise")}
    for folder in folders.values():
        folder.mkdir()
    for name in ("last.pt", "best.pt"):
        shutil.copyfile(args.run / name, folders["full"] / name)
        shutil.copyfile(args.run / name, folders["noise"] / name)
    save_checkpoint(folders["paused"] / "last.pt", compact_payload(last))
    save_checkpoint(folders["paused"] / "best.pt", compact_payload(best))
    noisy = dict(last)
    noisy["rng"] = torch.Generator().manual_seed(args.noise_seed).get_state()
    save_checkpoint(folders["noise"] / "last.pt", noisy)

    full_size = sum(_sizes(folders["full"]).values())
    paused_size = sum(_sizes(folders["paused"]).values())
    print(f"{model} on {benchmark} after {done} epochs ({args.run}):")
    for name in ("full", "paused"):
        sizes = ", ".join(f"{k} {v / 1e6:.1f} MB" for k, v in _sizes(folders[name]).items())
        print(f"  {name} state: {sizes}")
    print(f"  paused / full: {paused_size / full_size:.3f}")

    curves = {}
    for name, folder in folders.items():
        train(
            model,
            benchmark,
            RunOptions(
                out_dir=folder,
                resume=True,
                seed=last["seed"],
                max_batches=args.max_batches if args.max_batches else last.get("max_batches"),
                progress=False,
            ),
            recipe_overrides={
                "epochs": done + args.epochs,
                "precision": last["recipe"].get("precision", "float32"),
            },
        )
        history = read_checkpoint(folder / "last.pt")["history"][done:]
        curves[name] = [h["val_mpjpe"] for h in history]
    print(f"resumed for {args.epochs} epochs (max_batches {args.max_batches}), validation MPJPE:")
    print("  epoch   " + "".join(f"{name:>10}" for name in curves))
    for i in range(args.epochs):
        print(f"  {done + i + 1:5d}   " + "".join(f"{c[i]:10.3f}" for c in curves.values()))
    for name in ("paused", "noise"):
        gap = max(abs(a - b) for a, b in zip(curves[name], curves["full"]))
        print(f"  largest |{name} - full|: {gap:.3f} mm")
    shutil.rmtree(work)


if __name__ == "__main__":
    main()
