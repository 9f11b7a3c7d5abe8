"""``zoo weights export|import|pause|list``: a checkpoint's weights made shippable, weights from
outside the zoo imported, a paused training stored, and the shipped ones listed."""

from __future__ import annotations

import json
from pathlib import Path

from zoo.cli.common import (
    Deprecated,
    UsageError,
    add_command,
    common_options,
    registry_of,
    weights_dir_option,
)


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
    pause.add_argument(
        "--as",
        dest="name",
        metavar="NAME",
        help="store it as a run of its own under this name, beside the model's queue (a "
        "study's run: ltd_bf16_seed0); zoo train --out checkpoints/<benchmark>/NAME --resume "
        "continues it",
    )
    weights_dir_option(pause, "weights folder whose in_progress/ holds the paused states")
    imp = add_command(
        actions,
        "import",
        "make weights from outside the zoo (an authors' .pth state dict) shipped weights of a "
        "registered model, their keys mapped onto its own; the record names each source file's "
        "sha256 and address",
        import_foreign,
    )
    imp.add_argument(
        "sources",
        nargs="+",
        metavar="[PREFIX=]FILE",
        help="state dict file(s) (.pth, .pt, .bin); PREFIX= puts a file's keys under that "
        "prefix (a model of several parts saved apart: position.=model_position.pth)",
    )
    common_options(imp)
    imp.add_argument("--model", required=True, help="registered model the weights are for")
    imp.add_argument("--benchmark", required=True, help="benchmark the weights were trained on")
    imp.add_argument(
        "--key-map",
        metavar="YAML",
        help="{source prefix: zoo prefix} (null drops those keys); the longest prefix applies",
    )
    imp.add_argument(
        "--state-key",
        help="the key of the state dict inside a training script's saved dictionary "
        "(default: the file itself, or state_dict, model, net, ...)",
    )
    imp.add_argument("--label", help="label of the weights and their rows (default: MODEL@authors)")
    imp.add_argument(
        "--source",
        metavar="ADDRESS",
        help="where the files come from, recorded with the rows (e.g. "
        "github.com/OWNER/REPO/blob/COMMIT/checkpoints/model.pth)",
    )
    imp.add_argument("--licence", help="the licence the weights come under, as their authors say")
    imp.add_argument(
        "--redistributable",
        action="store_true",
        help="the licence allows shipping the weights in this repository (recorded)",
    )
    weights_dir_option(imp, "weights folder to write <benchmark>/<label>.safetensors in")
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


def import_foreign(args) -> int:
    from zoo.hub.foreign import import_weights, read_key_map
    from zoo.protocol.benchmark import get_benchmark

    sources = []
    for item in args.sources:
        # a file's own name may hold "=" (epoch=49-step=9999.ckpt): a file is a file
        prefix, _, file = ("", "", item) if Path(item).is_file() else item.partition("=")
        if not file or "/" in prefix or not Path(file).is_file():
            raise UsageError(f"{item}: no such file (expected [PREFIX=]FILE, a state dict)")
        sources.append((prefix, Path(file)))
    path = import_weights(
        sources,
        model=args.model,
        benchmark=get_benchmark(args.benchmark),
        registry=registry_of(args),
        key_map=read_key_map(args.key_map),
        state_key=args.state_key,
        label=args.label,
        origin=args.source,
        licence=args.licence,
        redistributable=args.redistributable,
        root=Path(args.weights_dir),
        data_root=args.data_root,
    )
    print(
        f"wrote {path} and {path.with_suffix('.json').name}; score it with: zoo eval --weights "
        f"{path}" + "".join(f" --registry {r}" for r in args.registry)
    )
    return 0


def pause_run(args) -> int:
    from zoo.hub.checkpoints import pause_run

    dest = pause_run(args.run, root=Path(args.weights_dir), epochs=args.epochs, name=args.name)
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
