"""The ``zoo`` command: list models, evaluate, regenerate leaderboards, train, build data.

One module per command (``zoo/cli/<command>.py``: its options in ``add``, its work in ``run``);
what they share is in :mod:`zoo.cli.common`. Nothing here imports torch until a command runs.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from zoo.cli import (
    cards,
    compare,
    costs,
    data,
    evaluate,
    leaderboard,
    list_models,
    render,
    site,
    train,
    weights,
)
from zoo.cli.common import (
    HelpFormatter,
    UsageError,
    action_first,
    check_device,
    in_flags,
    parse_overrides,
    registry_hint,
    shape_overrides,
)
from zoo.core.errors import ZooError

COMMANDS = (
    list_models,
    evaluate,
    leaderboard,
    costs,
    cards,
    site,
    compare,
    render,
    data,
    weights,
    train,
)


def build_parser() -> argparse.ArgumentParser:
    from zoo.core.version import __version__

    parser = argparse.ArgumentParser(
        prog="zoo",
        description="motion-zoo: list models, evaluate, regenerate leaderboards, train, "
        "build data.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"motion-zoo {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in COMMANDS:
        command.add(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    argv = sys.argv[1:] if argv is None else argv
    args = parser.parse_args(action_first(parser, argv))
    try:
        if getattr(args, "device", None) is not None:
            check_device(args.device)
        if getattr(args, "set", None):
            shape_overrides(parse_overrides(args.set), getattr(args, "benchmark", None))
        code = args.func(args)
        sys.stdout.flush()  # a closed pipe shows here, not at the interpreter's exit
        return code
    except ZooError as e:
        print(f"zoo {args.command}: error: {in_flags(e)}{registry_hint(e)}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # the reader left (zoo list | head): no traceback, no more output
        _discard_stdout()
        return 141
    except KeyboardInterrupt:
        print(
            f"zoo {args.command}: interrupted (nothing half-written is left; a training run "
            f"continues with --resume)",
            file=sys.stderr,
        )
        return 130
    except Exception as e:
        frames = _user_frames(e)
        if not frames:
            raise  # the zoo's own fault: the whole traceback, to report
        import traceback

        print(
            f"zoo {args.command}: error: your code raised {type(e).__name__}: {e}\n"
            f"(a model or registry file outside the zoo; its frames, innermost last:)",
            file=sys.stderr,
        )
        print("".join(traceback.format_list(frames)), end="", file=sys.stderr)
        return 1


def _user_frames(error: BaseException) -> list:
    """The frames of ``error``'s traceback in a researcher's own files: neither the zoo's
    package nor an installed library (site-packages) nor Python's own."""
    import sysconfig
    import traceback

    skip = [
        Path(__file__).resolve().parents[1],
        *{Path(sysconfig.get_paths()[k]).resolve() for k in ("stdlib", "purelib", "platlib")},
    ]
    return [
        frame
        for frame in traceback.extract_tb(error.__traceback__)
        if not frame.filename.startswith("<")
        and not any(Path(frame.filename).resolve().is_relative_to(s) for s in skip)
    ]


def _discard_stdout() -> None:
    """Point stdout at the null device, so that the interpreter's last flush of what the closed
    pipe did not take raises nothing."""
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (AttributeError, OSError, ValueError):  # a stdout without a descriptor (captured)
        pass


__all__ = ["UsageError", "build_parser", "main", "parse_overrides"]
