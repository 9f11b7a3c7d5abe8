"""``zoo list``: the registered models."""

from __future__ import annotations

import sys

from zoo.cli.common import UsageError, add_command, registry_of, registry_option


def add(sub) -> None:
    p = add_command(sub, "list", "list registered models", run)
    registry_option(p)
    p.add_argument(
        "--representation",
        metavar="KIND",
        help="only models of this representation (joints, expmap, mesh: what a model is fed)",
    )


def run(args) -> int:
    """Each model as a short block (as ``pip show`` does): name, representation, whether it
    trains, its description and its full reference, wrapped to the terminal."""
    import shutil
    import textwrap

    from zoo.core.errors import ZooError
    from zoo.hub.weights import unshipped_models
    from zoo.protocol.benchmark import MODEL_REPRESENTATIONS

    if args.representation is not None and args.representation not in MODEL_REPRESENTATIONS:
        raise UsageError(
            f"--representation: expected one of {', '.join(MODEL_REPRESENTATIONS)}, got "
            f"{args.representation!r}"
        )
    registry = registry_of(args)
    try:
        unshipped = unshipped_models(registry)
    except (ZooError, KeyError, TypeError, ValueError) as exc:  # as the site takes it
        print(f"warning: training status not shown: {exc}", file=sys.stderr)
        unshipped = {}
    width = min(100, shutil.get_terminal_size((100, 24)).columns)
    blocks = []
    for name in registry.list_models(args.representation):
        e = registry.get(name)
        trains = (
            "trainable"
            if e.trainable
            else (f"runs {e.weights_of}'s weights" if e.weights_of else "not trained")
        )
        if name in unshipped:
            trains += f"; {unshipped[name]}"
        lines = [f"{name}  ({'/'.join(e.representation)}; {trains})"]
        for label, text in (("", e.description), ("Reference: ", e.reference)):
            if text:
                lines += textwrap.wrap(
                    " ".join(str(text).split()),
                    width,
                    initial_indent="    " + label,
                    subsequent_indent="    ",
                )
        blocks.append("\n".join(lines))
    print("\n\n".join(blocks))
    print(f"\n{len(blocks)} model(s); hyper-parameters and recipes: docs/models/<model>.md")
    return 0
