"""``zoo train``: a model on a benchmark's training split."""

from __future__ import annotations

from zoo.cli.common import add_command, common_options, parse_overrides, registry_of


def add(sub) -> None:
    p = add_command(sub, "train", "train a model on a benchmark's training split", run)
    common_options(p)
    p.add_argument("--model", required=True, help="registered model name")
    p.add_argument("--benchmark", default="cmu", help="benchmark whose training split to learn")
    p.add_argument("--epochs", type=int, help="default: the registry recipe's")
    p.add_argument("--out", help="run folder (default: checkpoints/<benchmark>/<model>)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="model hyper-parameter")
    p.add_argument(
        "--train-set",
        action="append",
        metavar="KEY=VALUE",
        help="training-recipe override (lr, batch_size, ...)",
    )
    p.add_argument("--resume", action="store_true", help="continue from the run's last state")
    p.add_argument(
        "--init-from",
        metavar="PATH",
        help="start from this checkpoint (best.pt or last.pt) or shipped weights "
        "(.safetensors) of the same model and benchmark, with a fresh optimiser "
        "and schedule: a new stage of training, recorded with the source's budget",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of weights, order and dropout")
    p.add_argument("--max-batches", type=int, help="cap batches per epoch (quick runs)")
    p.add_argument(
        "--no-progress",
        action="store_true",
        help="no progress bar even on a terminal (a log or pipe never gets one)",
    )
    p.add_argument(
        "--cuda-graph",
        action="store_true",
        help="on one CUDA device, capture each epoch's step once as a CUDA graph and replay it "
        "(small models train several times faster; a step that reads values back to decide "
        "what to do cannot be captured and is refused)",
    )
    p.add_argument(
        "--compile",
        action="store_true",
        help="run the training loss through torch.compile: the same model and recipe, several "
        "times faster per step on a CPU once compiled (minutes); each epoch records it",
    )


def run(args) -> int:
    from zoo.train.loop import train
    from zoo.train.options import RunOptions

    if args.out:  # a file there, or an unwritable place, is refused before training
        from zoo.core.io import check_writable

        check_writable(args.out, what=f"--out {args.out}")
    registry = registry_of(args)
    options = RunOptions(
        seed=args.seed,
        device=args.device,
        data_root=args.data_root,
        out_dir=args.out,
        resume=args.resume,
        init_from=args.init_from,
        max_batches=args.max_batches,
        progress=not args.no_progress,
        cuda_graph=args.cuda_graph,
        compile=args.compile,
    )
    epochs = {"epochs": args.epochs} if args.epochs is not None else {}
    best = train(
        args.model,
        args.benchmark,
        options,
        registry=registry,
        overrides=parse_overrides(args.set),
        recipe_overrides={**parse_overrides(args.train_set), **epochs},
    )
    print(
        f"wrote {best} (best validation epoch) and {best.parent / 'last.pt'} (last epoch): "
        f"zoo eval --checkpoint {best} scores it, zoo leaderboard picks up "
        f"checkpoints/<benchmark>/<model>/, zoo weights export {best} ships it"
    )
    return 0
