"""``zoo weights export|list``: a checkpoint's weights made shippable, and the shipped ones."""

from __future__ import annotations

import json
from pathlib import Path

from zoo.cli.common import Deprecated, add_command, weights_dir_option


def add(sub) -> None:
    p = add_command(
        sub, "weights", "export a checkpoint's weights for shipping, or list the shipped ones", None
    )
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    e = add_command(
        actions, "export", "write a checkpoint's weights and record for shipping", export
    )
    e.add_argument("checkpoint", help="the checkpoint (best.pt or last.pt)")
    e.add_argument("--label", help="label (default: <model>, or <model>@last for last.pt)")
    e.add_argument(
        "--dtype",
        default="float16",
        choices=["float16", "float32"],
        help="storage precision (float16: half the size)",
    )
    weights_dir_option(e, "weights folder to write <benchmark>/<label>.safetensors in")
    e.add_argument("--root", dest="weights_dir", action=Deprecated, new="--weights-dir")
    pause = add_command(
        actions,
        "pause",
        "store a paused training (its last.pt and best.pt) as its model's one committed state "
        "under <weights-dir>/in_progress, compact (float16 weights, Adam moments in 8 bits and "
        "bfloat16); zoo train --resume continues it on any machine",
        pause_run,
    )
    pause.add_argument("run", help="the run's folder (e.g. checkpoints/cmu/spgsn)")
    pause.add_argument(
        "--epochs",
        type=int,
        help="the run's budget from here, larger than its recipe's (a run begun as a pilot); "
        "recorded as a recipe change, as zoo train --epochs on resume records it",
    )
    weights_dir_option(pause, "weights folder whose in_progress/ holds the paused states")
    listing = add_command(actions, "list", "the shipped weights, with their training budgets", show)
    weights_dir_option(listing, "weights folder")
    listing.add_argument("--root", dest="weights_dir", action=Deprecated, new="--weights-dir")


def export(args) -> int:
    from zoo.hub.checkpoints import export_weights

    path = export_weights(
        args.checkpoint, label=args.label, root=Path(args.weights_dir), dtype=args.dtype
    )
    print(f"wrote {path} and {path.with_suffix('.json').name}")
    return 0


def pause_run(args) -> int:
    from zoo.hub.checkpoints import pause_run

    dest = pause_run(args.run, root=Path(args.weights_dir), epochs=args.epochs)
    summary = json.loads((dest / "state.json").read_text())
    sizes = ", ".join(f"{name} {size / 1e6:.1f} MB" for name, size in summary["files"].items())
    print(
        f"wrote {dest} ({sizes}): {summary['model']} after {summary['epochs_run']} of "
        f"{summary['epochs_planned']} epochs; resume with: {summary['resume']}"
    )
    return 0


def show(args) -> int:
    from tabulate import tabulate

    from zoo.hub.weights import available_weights, read_weights_record, weights_file

    root = Path(args.weights_dir)
    rows = []
    for bench, label in available_weights(root):
        record = read_weights_record(weights_file(bench, label, root))
        training = record.training
        rows.append(
            [
                bench,
                label,
                record.model,
                f"{record.parameters / 1e6:.2f} M",
                record.dtype,
                training.get("samples_seen"),
                f"{training.get('seconds', 0) / 60:.0f}",
                training.get("device_name"),
            ]
        )
    headers = ["benchmark", "label", "model", "parameters", "stored as", "training samples",
               "minutes", "device"]  # fmt: skip
    print(tabulate(rows, headers=headers, tablefmt="github"))
    return 0
