"""Command-line conventions users know: ``zoo --version``, and no progress bars where nobody
watches (stderr not a terminal: a log file, a pipe, CI)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from zoo.core.version import __version__


def test_version():
    out = subprocess.run(
        [sys.executable, "-m", "zoo.cli", "--version"], capture_output=True, text=True
    )
    assert out.returncode == 0 and out.stdout.strip() == f"motion-zoo {__version__}"


def test_help_and_import_zoo_load_no_torch():
    """``zoo --help``, a command's help and ``import zoo`` answer without loading torch or pandas
    (they take seconds to import); the API loads them when first called."""
    probe = (
        "import sys\n"
        "from zoo.cli import main\n"
        "for argv in (['--help'], ['eval', '--help'], ['leaderboard', '--help']):\n"
        "    try:\n"
        "        main(argv)\n"
        "    except SystemExit:\n"
        "        pass\n"
        "import zoo\n"
        "assert callable(zoo.evaluate) and callable(zoo.compare), 'API not exported'\n"
        "heavy = sorted({'torch', 'pandas'} & set(sys.modules))\n"
        "print('HEAVY', heavy)\n"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "HEAVY []"


def test_no_progress_bars_when_stderr_is_not_a_terminal(capsys):
    from zoo.core.io import progress_bar

    # pytest captures stderr: no terminal, so no bar, whether or not one was asked for
    assert progress_bar(range(2)).disable and progress_bar(range(2), disable=False).disable
    assert progress_bar(range(2), disable=True).disable
    # every bar of the zoo comes from that one helper
    from pathlib import Path

    import zoo

    users = [
        p.name
        for p in Path(zoo.__file__).parent.rglob("*.py")
        if "from tqdm" in p.read_text() and p.name != "io.py"
    ]
    assert users == []


def test_list_shows_each_models_description_and_full_reference(capsys):
    from zoo.cli import main
    from zoo.models.registry import load_registry

    assert main(["list"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    mlp = load_registry().get("mlp")
    assert "siMLPe" in out and " ".join(mlp.reference.split()) in out
    assert " ".join(mlp.description.split()) in out


def test_every_option_of_every_command_has_help():
    import argparse

    from zoo.cli import build_parser

    missing = []

    def walk(parser, path):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, child in action.choices.items():
                    walk(child, [*path, name])
            elif action.option_strings and not action.help:
                missing.append(f"{' '.join(path)} {action.option_strings[0]}")

    walk(build_parser(), ["zoo"])
    assert missing == []


def test_nested_actions_take_only_their_own_options(capsys):
    """``zoo data basis`` offers --ship, not export's --window; ``zoo weights list`` no --dtype."""
    from zoo.cli import main

    for argv, own, foreign in (
        (["data", "basis", "--help"], "--ship", "--window"),
        (["data", "export", "--help"], "--window", "--ship"),
        (["weights", "list", "--help"], "--weights-dir", "--dtype"),
    ):
        with pytest.raises(SystemExit):
            main(argv)
        text = capsys.readouterr().out
        assert own in text and foreign not in text, argv


def test_defaults_are_shown_by_the_formatter(capsys):
    from zoo.cli import main
    from zoo.core.options import EVAL_BATCH

    with pytest.raises(SystemExit):
        main(["eval", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert f"windows per forward pass (default: {EVAL_BATCH})" in text
    assert "results root (default: results/)" in text
    assert "(default: None)" not in text and "(default: False)" not in text


def test_an_old_spelling_works_with_a_deprecation_line(tmp_path, capsys):
    """``--root`` (weights folder) became ``--weights-dir``: both list the same folder, the old
    one saying which replaces it."""
    from zoo.cli import main

    assert main(["weights", "list", "--weights-dir", str(tmp_path)]) == 0
    new = capsys.readouterr()
    assert main(["weights", "list", "--root", str(tmp_path)]) == 0
    old = capsys.readouterr()
    assert old.out == new.out
    assert "--root is deprecated, use --weights-dir" in old.err and "deprecated" not in new.err


def test_options_before_a_nested_action_parse_as_they_did(tmp_path, capsys):
    """Earlier releases took the action as a positional, so options could precede it
    (``zoo weights --root X list``); they still do, and only options move."""
    from zoo.cli import build_parser, main
    from zoo.cli.common import action_first

    parser = build_parser()
    assert action_first(parser, ["weights", "--weights-dir", "w", "list"]) == [
        "weights",
        "list",
        "--weights-dir",
        "w",
    ]
    assert action_first(parser, ["data", "--data-root=x", "describe", "cmu"]) == [
        "data",
        "describe",
        "--data-root=x",
        "cmu",
    ]
    # a folder named like an action is an option's value, not the action
    assert action_first(parser, ["data", "--data-root", "list", "build", "cmu"]) == [
        "data",
        "build",
        "--data-root",
        "list",
        "cmu",
    ]
    # argparse's unique prefix of a long option takes its value too
    assert action_first(parser, ["data", "--data", "list", "build", "cmu"]) == [
        "data",
        "build",
        "--data",
        "list",
        "cmu",
    ]
    for argv in (
        ["weights", "list", "--root", "w"],
        ["eval", "--model", "repeat_last"],
        ["weights", "-h", "list"],  # the command's help, not the action's
    ):
        assert action_first(parser, argv) == argv
    assert main(["weights", "list", "--weights-dir", str(tmp_path)]) == 0
    after = capsys.readouterr()
    assert main(["weights", "--weights-dir", str(tmp_path), "list"]) == 0
    assert capsys.readouterr().out == after.out


def test_compare_refuses_an_unknown_sampler_by_name(capsys):
    from zoo.cli import main

    assert main(["compare", "a", "b", "--benchmark", "cmu", "--sampler", "ltd9"]) == 2
    err = capsys.readouterr().err
    assert "--sampler 'ltd9': unknown for benchmark cmu; valid: ltd8, all (its tables)" in err


def test_a_reader_that_leaves_ends_the_command_quietly():
    """``zoo list | head``: the pipe closes before zoo writes; no traceback, exit 141."""
    process = subprocess.Popen(
        [sys.executable, "-c", "import sys; from zoo.cli import main; sys.exit(main(['list']))"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    process.stdout.close()  # the reader is gone before the first write
    _, err = process.communicate(timeout=120)
    assert process.returncode == 141 and err == b""


def test_compare_help_states_the_block_length_the_bootstrap_uses(capsys):
    import re

    from zoo.cli import main
    from zoo.stats.intervals import BLOCK_WINDOWS

    with pytest.raises(SystemExit):
        main(["compare", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    said = re.search(r"default: (\d+) window lengths", text)
    assert said and int(said.group(1)) == BLOCK_WINDOWS
