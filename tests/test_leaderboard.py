"""zoo leaderboard: one command re-evaluates what it can and refuses stale protocols."""

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import Pristine, write_cmu_file
from tiny_models import REGISTRY

from zoo.cli import main
from zoo.core.errors import EvaluationError
from zoo.evaluation.results import EvalResult, read_table
from zoo.leaderboard.plan import Plan
from zoo.leaderboard.rebuild import regenerate
from zoo.models.registry import Registry
from zoo.report.outputs import write_leaderboard
from zoo.train.loop import train
from zoo.train.options import RunOptions

HERE = Path(__file__).resolve().parent


def cmu_and_registry(tmp_path):
    """Two training files and one test file of CMU walking, and the zoo's registry plus the
    tiny test models."""
    root = tmp_path / "cmu"
    for split, n in (("train", 2), ("test", 1)):
        for i in range(1, n + 1):
            write_cmu_file(root / split / "walking" / f"walking_{i}.txt", 0.01 * i * np.arange(800))
    (tmp_path / "registry.yaml").write_text(REGISTRY)
    shutil.copy(HERE / "tiny_models.py", tmp_path / "tiny_models.py")
    return root, registry_in(tmp_path)


def registry_in(folder):
    """The zoo's registry plus the tiny test models' registry file in ``folder``."""
    return Registry.from_files(HERE.parent / "registry.yaml", folder / "registry.yaml")


def trained_tiny(tmp_path, **options):
    """The CMU copy and registry of :func:`cmu_and_registry`, and the checkpoints folder where
    ``tiny`` was just trained for one epoch (``options``: more of :class:`RunOptions`' fields)."""
    root, registry = cmu_and_registry(tmp_path)
    checkpoints = tmp_path / "checkpoints"
    options = RunOptions(
        data_root=root, progress=False, out_dir=checkpoints / "cmu" / "tiny", **options
    )
    train("tiny", "cmu", options, registry=registry, recipe_overrides={"epochs": 1})
    return root, registry, checkpoints


@pytest.fixture(scope="module")
def _boards(tmp_path_factory):
    """The boards several tests start from, each built once for the module: ``baseline``,
    :func:`cmu_and_registry` and repeat_last's tables; ``trained``, :func:`trained_tiny` and
    the tables of tiny's checkpoint beside repeat_last."""
    folder = tmp_path_factory.mktemp("leaderboard")

    def baseline(tmp):  # as a user builds it, results/README.md included
        root, _ = cmu_and_registry(tmp)
        assert main(
            ["leaderboard", "--registry", str(tmp / "registry.yaml"), "--benchmark", "cmu",
             "--data-root", str(root), "--results", str(tmp / "results"),
             "--weights-dir", str(tmp / "no_weights"), "--checkpoints", str(tmp / "no_checkpoints")]
        ) == 0  # fmt: skip

    def trained(tmp):
        root, registry, checkpoints = trained_tiny(tmp)
        written = regenerate(
            "cmu", registry=registry, data_root=root, out_root=tmp / "results",
            checkpoints=checkpoints,
        )  # fmt: skip
        assert [p.name for p in written] == ["ltd8", "all"]

    return {
        "baseline": Pristine(folder / "baseline", baseline),
        "trained": Pristine(folder / "trained", trained),
    }


@pytest.fixture
def baseline(_boards):
    """:func:`cmu_and_registry`'s folder with repeat_last's tables in ``results``, as built."""
    return _boards["baseline"].restore()


@pytest.fixture
def trained_board(_boards):
    """:func:`trained_tiny`'s folder with the tables of tiny (its checkpoint) and repeat_last
    in ``results``, as built."""
    return _boards["trained"].restore()


def test_regenerate_with_checkpoint_and_stale_result(trained_board, tmp_path, capsys):
    root, registry = trained_board / "cmu", registry_in(trained_board)
    checkpoints, out = trained_board / "checkpoints", trained_board / "results"
    written = regenerate(
        "cmu", registry=registry, data_root=root, out_root=out, checkpoints=checkpoints
    )
    assert [p.name for p in written] == ["ltd8", "all"]
    board = (out / "cmu" / "all" / "leaderboard.md").read_text()
    assert "| tiny " in board and "| repeat_last " in board
    assert (out / "cmu" / "all" / "mpjpe.png").stat().st_size > 0  # one plot per metric
    combined = read_table(out / "cmu" / "all").frame
    assert set(combined.model) == {"tiny", "repeat_last"}
    assert combined.protocol_id.nunique() == 1
    # each row's numbers are kept once, in its own folder
    assert not (out / "cmu" / "all" / "results.csv").exists()
    assert combined.equals(
        pd.concat(
            [pd.read_csv(out / "cmu" / "all" / m / "results.csv") for m in ("repeat_last", "tiny")],
            ignore_index=True,
        )
    )

    # Without its checkpoint the trained model's stored result is kept while it still matches
    # (the same table, rows in the same order: a fresh clone rewrites no stored number)...
    shutil.rmtree(checkpoints)
    regenerate("cmu", registry=registry, data_root=root, out_root=out, checkpoints=checkpoints)
    assert "| tiny " in (out / "cmu" / "all" / "leaderboard.md").read_text()
    assert read_table(out / "cmu" / "all").frame.to_csv(index=False) == combined.to_csv(index=False)
    # a table an older zoo wrote (a table-wide results.csv beside its rows) loses that copy
    (out / "cmu" / "all" / "results.csv").write_text(combined.to_csv(index=False))
    regenerate("cmu", registry=registry, data_root=root, out_root=out, checkpoints=checkpoints)
    assert not (out / "cmu" / "all" / "results.csv").exists()
    runs = [EvalResult.read(out / "cmu" / "all" / name) for name in ("tiny", "repeat_last")]
    for order, folder in ((runs, "a"), (runs[::-1], "b")):
        write_leaderboard(order, tmp_path / folder)
    for name in ("protocol.json", "leaderboard.md"):
        assert (tmp_path / "a" / name).read_text() == (tmp_path / "b" / name).read_text()
    # a table read without the row folders it lists says which one is missing
    with pytest.raises(EvaluationError, match=r"a/repeat_last/results.csv: missing"):
        read_table(tmp_path / "a")
    # ...and left out, with the difference named, once the data under it changed.
    stored = out / "cmu" / "all" / "tiny" / "protocol.json"
    record = json.loads(stored.read_text())
    record["files"][0]["sha256"] = "0" * 64
    stored.write_text(json.dumps(record))
    regenerate("cmu", registry=registry, data_root=root, out_root=out, checkpoints=checkpoints)
    assert "| tiny " not in (out / "cmu" / "all" / "leaderboard.md").read_text()
    assert "different sha256: ['test/walking/walking_1.txt']" in capsys.readouterr().err


def test_fully_trained_checkpoint_joins_as_model_at_last(tmp_path):
    root, registry = cmu_and_registry(tmp_path)
    checkpoints = tmp_path / "checkpoints"
    # Two epochs that change nothing: validation never improves after epoch 1, so best.pt is
    # epoch 1 (early-stopped) and last.pt epoch 2 (fully trained).
    train(
        "tiny",
        "cmu",
        RunOptions(data_root=root, progress=False, out_dir=checkpoints / "cmu" / "tiny"),
        registry=registry,
        recipe_overrides={"lr": 0.0, "epochs": 2},
    )
    out = tmp_path / "results"
    regenerate("cmu", registry=registry, data_root=root, out_root=out, checkpoints=checkpoints)
    combined = read_table(out / "cmu" / "all").frame
    assert set(combined.model) == {"tiny", "tiny@last", "repeat_last"}
    record = json.loads((out / "cmu" / "all" / "tiny@last" / "protocol.json").read_text())
    assert record["provenance"]["checkpoint"].endswith("last.pt")
    assert record["provenance"]["training"]["epochs_run"] == 2
    assert record["provenance"]["hparams"]["hidden"] == 16  # as zoo eval --checkpoint records


def test_a_row_from_a_run_short_of_its_recipe_is_marked_where_its_number_is(tmp_path):
    """A researcher's row scored from zoo train's checkpoint after one capped epoch of a
    2-epoch recipe: the Markdown table and the site mark it, saying what its run saw."""
    from zoo.site import build_site

    root, registry, checkpoints = trained_tiny(tmp_path, max_batches=1)
    out = tmp_path / "results"
    regenerate("cmu", registry=registry, data_root=root, out_root=out, checkpoints=checkpoints)
    board = (out / "cmu" / "all" / "leaderboard.md").read_text()
    record = json.loads((out / "cmu" / "all" / "tiny" / "protocol.json").read_text())
    run = record["provenance"]
    assert run["max_batches"] == 1 and run["recipe"]["epochs"] == 1  # the run's own, as it ran
    seen = run["training"]["samples_seen"]
    assert seen == 8  # one batch of 8
    windows = run["validation"]["training_windows"]
    full = 2 * (windows // 8) * 8  # the registry's recipe: 2 epochs of batch 8
    said = f"its run saw {seen / full:.2%} of its recipe's training windows ({seen:,} of {full:,})"
    assert seen / full < 0.01  # under 1%: shown to two decimals, not as "0%"
    assert "| tiny †" in board and said in board and "| repeat_last †" not in board
    site = build_site(tmp_path / "site", out, registry=registry).out
    assert said in (site / "table-cmu-all.html").read_text()


def test_completion_models_get_their_own_tables(baseline, capsys):
    root, registry = baseline / "cmu", registry_in(baseline)
    checkpoints, out = baseline / "checkpoints", baseline / "results"
    # Only baselines for completion: no completion table.
    regenerate("cmu", registry=registry, data_root=root, out_root=out, checkpoints=checkpoints)
    assert not (out / "cmu" / "all-completion").exists()
    # Validation during training gives the model each window's final frame.
    train(
        "tiny_completion",
        "cmu",
        RunOptions(data_root=root, progress=False, out_dir=checkpoints / "cmu" / "tiny_completion"),
        registry=registry,
    )
    regenerate("cmu", registry=registry, data_root=root, out_root=out, checkpoints=checkpoints)
    completion = read_table(out / "cmu" / "all-completion").frame
    assert set(completion.model) == {"tiny_completion", "interpolate"}
    assert set(completion.task) == {"completion"}
    prediction = read_table(out / "cmu" / "all").frame
    assert set(prediction.model) == {"repeat_last"}  # no trained predictor here
    assert set(prediction.task) == {"prediction"}
    # The interpolation ends exactly on the given final frame.
    last = completion[
        (completion.model == "interpolate")
        & (completion.frame == 25)
        & (completion.averaging == "frame")
    ]
    assert (last.value.abs() < 1e-3).all()


def test_results_folder_names_sampler_task_and_ground_truth():
    from zoo.store.layout import table_folder

    assert table_folder("all") == "all"
    assert table_folder("all", "completion", "spectral") == "all-completion-gt_spectral"
    assert table_folder("stride5_strict", "longterm", "raw", 50) == "stride5_strict-longterm50"
    assert table_folder("all", truth="spectral", melv="raw") == "all-gt_spectral-melv_raw"


def test_check_recomputes_every_row_and_names_what_differs(trained_board, capsys):
    root = trained_board / "cmu"
    checkpoints, out = trained_board / "checkpoints", trained_board / "results"
    common = [
        "--registry",
        str(trained_board / "registry.yaml"),
        "--data-root",
        str(root),
        "--out",
        str(out),
        "--checkpoints",
        str(checkpoints),
        "--weights",
        str(trained_board / "weights"),
    ]
    assert main(["leaderboard", "--benchmark", "cmu", *common]) == 0
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}
    capsys.readouterr()
    # every committed benchmark (cmu), every window (--full: the averages recomputed too)
    assert main(["leaderboard", "--check", "--full", *common]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-2].startswith(
        "checked 4 leaderboard rows (2 models: repeat_last, tiny) in 2 tables, on 374 of their "
        "374 windows: largest difference "
    )
    assert "relative, 0.00 of its tolerance)" in lines[-2]
    assert lines[-1] == (
        "tolerance: mpjpe: |difference| <= 1.5e-05 x |value| + 0.002 mm (a std: the tolerance "
        "of its mean)"
    )
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()} == before
    assert lines[0].startswith("cmu/ltd8: 2 rows on all 8 windows (walking 8), largest ")
    assert ": passed (" in lines[0] and lines[1].startswith("cmu/all: 2 rows on all")

    # a row that cannot be loaded (a corrupted checkpoint) is reported and the check goes on
    best = checkpoints / "cmu" / "tiny" / "best.pt"
    saved = best.read_bytes()
    best.write_bytes(b"not a checkpoint")
    assert main(["leaderboard", "--check", *common]) == 1
    captured = capsys.readouterr()
    assert "checking cmu/all: repeat_last" in captured.err  # progress: the rows of each pass
    assert "cmu/all/tiny: not recomputed:" not in captured.err
    assert "cmu/all: tiny: not recomputed:" in captured.err
    table_lines = [line for line in captured.out.splitlines() if line.startswith("cmu/")]
    # one problem per table (the row not recomputed), not one per committed value of it
    assert len(table_lines) == 2 and all("1 problem(s), first: cmu/" in t for t in table_lines)
    assert table_lines[1].startswith("cmu/all: 2 rows on 32 of 366 windows (walking 32)")
    best.write_bytes(saved)

    for label, horizon, averaging, column in (
        ("tiny", 400, "frame", "value"),
        ("repeat_last", 80, "cumulative", "std"),
    ):
        row = out / "cmu" / "all" / label / "results.csv"
        frame = pd.read_csv(row)
        frame.loc[
            (frame.horizon_ms == horizon)
            & (frame.action == "average")
            & (frame.averaging == averaging)
            & (frame.joints == "all38"),
            column,
        ] += 0.01
        frame.to_csv(row, index=False)
    (out / "cmu" / "ltd8" / "repeat_last" / "windows.npz").unlink()
    assert main(["leaderboard", "--check", "--full", "--benchmark", "cmu", *common]) == 1
    captured = capsys.readouterr()
    for label, what in (("tiny", "averaging=frame"), ("repeat_last", "averaging=cumulative")):
        row = out / "cmu" / "all" / label / "results.csv"
        # named twice: against the recomputation and against its own windows.npz
        assert f"cmu/all: model={label}, action=average, metric=mpjpe, {what}" in captured.err
        assert f"{row}: model={label}, action=average, metric=mpjpe, {what}" in captured.err
    assert "ltd8/repeat_last/windows.npz: missing" in captured.err
    assert "5 problem(s) above" in captured.out

    # a trained row whose checkpoint is gone cannot be recomputed: a problem, never kept
    shutil.rmtree(checkpoints)
    assert main(["leaderboard", "--check", "--benchmark", "cmu", *common]) == 1
    assert "all/tiny: cannot be recomputed" in capsys.readouterr().err


def test_results_index_lists_every_table_with_its_headline(baseline):
    from zoo.report.outputs import write_index

    text = write_index(baseline / "results").read_text()
    assert text.startswith("# Results") and "zoo leaderboard --check" in text
    for folder in ("cmu/all", "cmu/ltd8"):
        assert f"### {folder}\n" in text and f"]({folder}/leaderboard.md)" in text
    assert text.count("#### Headline: MPJPE (mm), averaging `frame`, joints `all38`") == 2
    assert "| repeat_last" in text


def test_the_committed_results_index_is_what_the_tables_write():
    """results/README.md is generated (zoo leaderboard writes it): edited code or tables that
    would change it leave it stale, and the README's first command would change a tracked file."""
    from zoo.report.outputs import index_text
    from zoo.store.layout import RESULTS_DIR

    assert index_text(RESULTS_DIR) == (RESULTS_DIR / "README.md").read_text(), (
        "results/README.md is stale: python -c 'from zoo.report.outputs import write_index; "
        'write_index("results")\' rewrites it'
    )


def test_an_interrupted_leaderboard_leaves_the_old_folder_whole(baseline, monkeypatch):
    root, registry, out = baseline / "cmu", registry_in(baseline), baseline / "results"
    folder = out / "cmu" / "all"
    before = {p.relative_to(folder): p.read_bytes() for p in folder.rglob("*") if p.is_file()}

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("zoo.report.outputs.plot_average", interrupted)
    with pytest.raises(KeyboardInterrupt):
        regenerate(
            "cmu", registry=registry, data_root=root, out_root=out, plan=Plan(recompute=True)
        )
    after = {p.relative_to(folder): p.read_bytes() for p in folder.rglob("*") if p.is_file()}
    assert after == before and (folder / "mpjpe.png").is_file()
    leftovers = [
        p.name
        for p in (out / "cmu").iterdir()
        if p.name.startswith(".") and not p.name.endswith(".lock")
    ]
    assert leftovers == []


def test_a_model_asked_for_by_name_without_weights_is_an_error_naming_where_it_looked(
    tmp_path, capsys
):
    """--model of a trainable model with no shipped weights and no checkpoint: not '22 rows
    reused, 0 recomputed' and exit 0, but one error naming the files it looked for; nothing
    written."""
    from zoo.store.layout import StoreError

    root, registry = cmu_and_registry(tmp_path)
    out = tmp_path / "results"
    with pytest.raises(StoreError, match=r"--model tiny \(looked for .*tiny.safetensors and "):
        regenerate(
            "cmu",
            registry=registry,
            data_root=root,
            out_root=out,
            checkpoints=tmp_path / "checkpoints",
            weights=tmp_path / "weights",
            plan=Plan(models=frozenset({"tiny"})),
        )
    assert not out.exists()
    code = main(
        ["leaderboard", "--registry", str(tmp_path / "registry.yaml"), "--benchmark", "cmu",
         "--model", "tiny", "--data-root", str(root), "--results", str(out)]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert code != 0 and "no trained weights to score, so no row; train it" in err
    assert "Traceback" not in err


def test_base_shows_ones_rows_beside_the_committed_ones_and_never_writes_them(baseline, tmp_path):
    """--base RESULTS: the committed tables are the start, the user's rows go under --results
    beside them, and RESULTS is left byte for byte as it was."""
    root, registry = baseline / "cmu", registry_in(baseline)
    base, mine = baseline / "results", tmp_path / "mine"  # base: repeat_last's tables
    common = ["--registry", str(baseline / "registry.yaml"), "--benchmark", "cmu",
              "--data-root", str(root), "--weights-dir", str(tmp_path / "no_weights")]  # fmt: skip
    before = {p: p.read_bytes() for p in base.rglob("*") if p.is_file()}
    checkpoints = tmp_path / "checkpoints"
    train(
        "tiny",
        "cmu",
        RunOptions(data_root=root, progress=False, out_dir=checkpoints / "cmu" / "tiny"),
        registry=registry,
        recipe_overrides={"epochs": 1},
    )
    args = ["--base", str(base), "--results", str(mine), "--checkpoints", str(checkpoints)]
    assert main(["leaderboard", *common, "--model", "tiny", *args]) == 0
    labels = set(read_table(mine / "cmu" / "all").frame.model)
    assert {"tiny", "repeat_last"} <= labels
    assert {p: p.read_bytes() for p in base.rglob("*") if p.is_file()} == before
    assert main(["leaderboard", *common, "--base", str(mine), "--results", str(mine)]) == 2


def test_base_with_an_unknown_model_writes_nothing(tmp_path, capsys):
    root, _ = cmu_and_registry(tmp_path)
    (tmp_path / "committed" / "cmu" / "all").mkdir(parents=True)
    code = main(
        ["leaderboard", "--benchmark", "cmu", "--model", "nosuch", "--data-root", str(root),
         "--base", str(tmp_path / "committed"), "--results", str(tmp_path / "mine")]
    )  # fmt: skip
    assert code == 2 and "unknown model 'nosuch'" in capsys.readouterr().err
    assert not (tmp_path / "mine").exists()


def test_a_plot_drawn_from_the_same_rows_is_copied_and_any_change_draws_it_again(
    tmp_path, monkeypatch
):
    """A table's plot keeps a digest of what it shows (rows, title, styles, plotting code): a
    rebuild with the same inputs copies the stored plot byte for byte, any change draws it."""
    from zoo.core.io import figure_drawn_from, save_figure
    from zoo.report.outputs import plot_average

    frame = pd.DataFrame(
        [
            {"action": action, "metric": "mpjpe", "averaging": "frame", "joints": "all",
             "model": model, "horizon_ms": h, "value": v * h / 80}
            for action in ("walking", "average")
            for model, v in (("repeat_last", 10.0), ("ltd", 7.0))
            for h in (80, 160, 320)
        ]
    )  # fmt: skip
    (drawn,) = plot_average(frame, tmp_path / "a", "a table")
    key = figure_drawn_from(drawn)
    assert key and len(key) == 64
    draws = []
    monkeypatch.setattr(
        "zoo.report.outputs.save_figure", lambda *a, **k: draws.append(a[1]) or save_figure(*a, **k)
    )
    (copied,) = plot_average(frame, tmp_path / "b", "a table", previous=tmp_path / "a")
    assert draws == [] and copied.read_bytes() == drawn.read_bytes()

    changed = frame.copy()
    changed.loc[changed["action"] == "average", "value"] += 1e-9  # below any printed digit
    walking = frame.copy()
    walking.loc[walking["action"] == "walking", "value"] += 1.0  # not drawn: no redraw
    for other, title, where in (
        (changed, "a table", "c"),
        (frame, "another title", "d"),
        (walking, "a table", "e"),
    ):
        (path,) = plot_average(other, tmp_path / where, title, previous=tmp_path / "a")
        assert (path in draws) == (where != "e")
        assert (figure_drawn_from(path) == key) == (where == "e")
    # another colour for a model (the palette, or the registry's order) draws it again
    monkeypatch.setattr("zoo.report.outputs.PALETTE", ("#000000", "#ffffff"))
    (path,) = plot_average(frame, tmp_path / "g", "a table", previous=tmp_path / "a")
    assert draws[-1] == path and figure_drawn_from(path) != key
    monkeypatch.undo()
    # a stored plot without a digest (as drawn before digests were kept), or not a PNG, is
    # drawn again
    import matplotlib.pyplot as plt

    for stored in ("unkeyed", "not a png"):
        folder = tmp_path / stored
        folder.mkdir()
        if stored == "unkeyed":
            save_figure(plt.subplots()[0], folder / "mpjpe.png")
        else:
            (folder / "mpjpe.png").write_bytes(b"not a png")
        draws.clear()
        monkeypatch.setattr(
            "zoo.report.outputs.save_figure",
            lambda *a, **k: draws.append(a[1]) or save_figure(*a, **k),
        )
        (path,) = plot_average(frame, tmp_path / f"{stored}-again", "a table", previous=folder)
        assert draws == [path] and figure_drawn_from(path) == key


@pytest.mark.parametrize("table", ["cmu/ltd8", "cloth/all", "cmu_anny_oi/stride5_strict"])
def test_the_fixed_margins_hold_every_label_of_a_committed_table(tmp_path, monkeypatch, table):
    """The average plots' margins are fixed (no layout pass measures the text): every axis's
    labels, ticks, title and legend lie inside the figure and clear of the next panel."""
    import zoo.report.outputs as outputs
    from zoo.core.io import save_figure
    from zoo.paths import REPO_ROOT

    drawn = []

    def measured(fig, path, drawn_from=None, *, tight=True):
        renderer = fig.canvas.get_renderer()
        width, height = fig.bbox.width, fig.bbox.height
        boxes = [ax.get_tightbbox(renderer) for ax in fig.axes]
        assert all(b.x0 >= 0 and b.y0 >= 0 and b.x1 <= width and b.y1 <= height for b in boxes)
        assert all(a.x1 < b.x0 for a, b in zip(boxes, boxes[1:]))
        drawn.append(path)
        save_figure(fig, path, drawn_from, tight=tight)

    folder = REPO_ROOT / "results" / table
    monkeypatch.setattr(outputs, "save_figure", measured)
    outputs.plot_average(
        read_table(folder).frame,
        tmp_path,
        outputs.table_title((folder / "leaderboard.md").read_text()),
    )
    assert drawn


def test_every_committed_plot_carries_the_digest_of_what_it_shows_now():
    """A plot whose digest is not the one the current code gives would be drawn again by the
    next rebuild, rewriting a PNG whose pixels did not change: a change to the drawing code
    redraws the committed plots in the same commit. Held where matplotlib is the version they
    were drawn with (pinned in pyproject.toml; Python 3.10 gets another, which draws anew)."""
    import matplotlib
    from PIL import Image

    from zoo.core.io import figure_drawn_from
    from zoo.paths import REPO_ROOT
    from zoo.report.outputs import (
        TRAINING_PLOT,
        plot_digests,
        table_title,
        training_curves,
        training_curves_digest,
        training_plot_title,
    )
    from zoo.stats.sensitivity import protocol_sensitivity

    tables = sorted((REPO_ROOT / "results").glob("*/*/leaderboard.md"))
    assert len(tables) >= 10
    with Image.open(min(tables[0].parent.glob("*.png"))) as image:
        drawn_by = image.text.get("Software", "")  # "Matplotlib version3.11.2, https://..."
    if f"version{matplotlib.__version__}," not in drawn_by:
        pytest.skip(
            f"committed plots drawn by {drawn_by!r}, not matplotlib {matplotlib.__version__}"
        )
    stale = []
    for md in tables:
        digests = plot_digests(read_table(md.parent).frame, table_title(md.read_text()))
        stale += [
            str(md.parent / name)
            for name, digest in digests.items()
            if figure_drawn_from(md.parent / name) != digest
        ]
    for png in sorted((REPO_ROOT / "results").glob(f"*/{TRAINING_PLOT}")):
        curves = training_curves(REPO_ROOT / "weights", png.parent.name)
        if figure_drawn_from(png) != training_curves_digest(
            curves, training_plot_title(png.parent.name)
        ):
            stale.append(str(png))
    for png in sorted((REPO_ROOT / "results").glob("*/sensitivity.png")):
        if figure_drawn_from(png) != protocol_sensitivity(png.parent).plot_digest():
            stale.append(str(png))
    assert not stale, f"plots to draw again (zoo leaderboard): {stale[:5]}"


def test_a_base_gives_its_costs_and_training_curves_to_a_results_folder_without_them(tmp_path):
    """The curves of the shipped models come with --base, so an outside model's leaderboard
    does not draw them again; a results folder's own files are never replaced."""
    from zoo.leaderboard.rebuild import copy_benchmark_tables

    base, mine = tmp_path / "base" / "cmu", tmp_path / "mine" / "cmu"
    base.mkdir(parents=True)
    (base / "costs.json").write_text("{}")
    (base / "training.png").write_bytes(b"curves")
    copy_benchmark_tables(tmp_path / "base", tmp_path / "mine", "cmu")
    assert (mine / "training.png").read_bytes() == b"curves"
    assert (mine / "costs.json").read_text() == "{}"
    (base / "training.png").write_bytes(b"other curves")
    copy_benchmark_tables(tmp_path / "base", tmp_path / "mine", "cmu")
    assert (mine / "training.png").read_bytes() == b"curves"
