"""zoo site without a browser: the table as data beside each leaderboard, the clips file, the
pages built from committed results, and bad input shown on its page and warned about."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from tiny_models import weights_record

from zoo.cli import main
from zoo.evaluation.markdown import headline_key
from zoo.evaluation.results import EvalResult, table_labels
from zoo.hub.weights import unshipped_models
from zoo.models.registry import load_registry
from zoo.paths import REPO_ROOT
from zoo.report.clips import Clips, cluster_vertices
from zoo.report.tables import table_summary
from zoo.site import build_site

RESULTS = REPO_ROOT / "results"
TABLE = RESULTS / "cmu_anny_oi_low" / "stride5_strict"


def _copy_results(tmp_path: Path, *benchmarks: str) -> Path:
    root = tmp_path / "results"
    for bench in benchmarks:
        shutil.copytree(RESULTS / bench, root / bench, ignore=shutil.ignore_patterns("*.npz"))
    return root


@pytest.fixture(scope="module")
def cmu_site(tmp_path_factory) -> tuple[Path, Path]:
    """The committed CMU results copied and their site built, once for the tests that only
    read them: ``(results, site)``."""
    tmp = tmp_path_factory.mktemp("cmu_site")
    results = _copy_results(tmp, "cmu")
    build_site(tmp / "site", results)
    return results, tmp / "site"


@pytest.fixture(scope="module")
def table():
    """TABLE's rows and their summary, made once for the tests that read them."""
    rows = [EvalResult.read(TABLE / label) for label in table_labels(TABLE)]
    return rows, table_summary(rows)


def test_summary_matches_the_rows_and_the_markdown_headline(table):
    rows, summary = table
    stored = json.loads((TABLE / "summary.json").read_text())
    metric, joints = headline_key(rows[0].protocol)
    view = summary["views"][0]
    assert (view["metric"], view["averaging"], view["joints"], view["headline"]) == (
        metric,
        "frame",
        joints,
        True,
    )
    # every value is the row's own results.csv value, to the 7 digits stored
    frame = rows[1].frame
    model = str(frame["model"].iloc[0])
    mine = next(m for m in view["models"] if m["model"] == model)
    for h, value in zip(view["horizons_ms"], mine["values"]):
        csv_value = frame[
            (frame.metric == metric)
            & (frame.averaging == "frame")
            & (frame.joints == joints)
            & (frame.action == "average")
            & (frame.model == model)
            & (frame.horizon_ms == h)
        ]["value"].item()
        assert value == pytest.approx(csv_value, rel=1e-6)
    # the committed summary.json is this table's, number for number
    stored_view = next(v for v in stored["views"] if v["headline"])
    assert [m["model"] for m in stored_view["models"]] == [m["model"] for m in view["models"]]
    for kept, fresh in zip(stored_view["models"], view["models"]):
        assert kept["values"] == pytest.approx(fresh["values"], rel=1e-6)
        assert kept["bold"] == fresh["bold"]
    assert stored_view["best"] == view["best"]
    # the bold cells are the Markdown headline's bold cells
    markdown = (TABLE / "leaderboard.md").read_text().split("## Headline", 1)[1]
    line = next(row for row in markdown.splitlines() if row.startswith(f"| {model} "))
    cells = [c.strip() for c in line.strip("|").split("|")][1 : 1 + len(view["horizons_ms"])]
    assert [c.startswith("**") for c in cells] == mine["lowest"]
    assert [c.startswith("*") for c in cells] == mine["bold"]  # italic: not distinguishable


def test_cumulative_view_is_the_running_mean_of_the_frame_view(table):
    views = {(v["metric"], v["averaging"]): v for v in table[1]["views"]}
    frame, cumulative = views[("rmse", "frame")], views[("rmse", "cumulative")]
    model = frame["models"][0]
    curve = np.array([v for _, v in model["curve"]])
    running = np.cumsum(curve) / np.arange(1, len(curve) + 1)
    other = next(m for m in cumulative["models"] if m["model"] == model["model"])
    assert np.allclose([v for _, v in other["curve"]], running, rtol=1e-5)


def test_clusters_keep_a_small_mesh_and_shrink_a_large_one():
    grid = np.stack(np.meshgrid(np.arange(40.0), np.arange(40.0), [0.0]), -1).reshape(-1, 3)
    quads = [(i * 40 + j, i * 40 + j + 1, (i + 1) * 40 + j) for i in range(39) for j in range(39)]
    faces = np.array(quads)
    kept, same = cluster_vertices(grid, faces, target=2000)
    assert len(kept) == 1600 and same is faces
    kept, fewer = cluster_vertices(grid, faces, target=300)
    assert 150 <= len(kept) <= 300
    assert fewer.max() < len(kept) and len(fewer) > 100
    assert (fewer[:, 0] != fewer[:, 1]).all()


def _clips(faces=None) -> Clips:
    t = np.linspace(0, 1, 6)[None, :, None, None]
    base = np.array([[0, 0, 0], [100, 0, 0], [0, 100, 0], [0, 0, 1700.0]])[None, None]
    truth = np.repeat(base + 50 * t, 2, axis=0)
    return Clips(
        benchmark="cmu_anny_oi_low",
        fps=25.0,
        input_frames=3,
        windows=np.array([3, 9]),
        sequences=["walking_1", "running_1"],
        faces=np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]) if faces is None else faces,
        vertices=np.arange(4),
        truth=truth,
        predictions={"spectrhums": truth[:, 3:] + 7.0},
    )


def test_clips_round_trip_to_the_millimetre(tmp_path):
    clips = _clips()
    back = Clips.read(clips.write(tmp_path / "clips.npz"))
    assert np.abs(back.truth - clips.truth).max() <= 0.5
    assert np.abs(back.predictions["spectrhums"] - clips.predictions["spectrhums"]).max() <= 0.5
    assert back.sequences == clips.sequences and back.input_frames == 3


def test_site_from_committed_results(tmp_path):
    results = _copy_results(tmp_path, "cmu_anny_oi_low")
    _clips().write(results / "cmu_anny_oi_low" / "clips.npz")
    build = build_site(tmp_path / "site", results)
    assert build.warnings == []
    pages = set(build.pages)
    assert {
        "index.html",
        "bench-cmu_anny_oi_low.html",
        "table-cmu_anny_oi_low-stride5_strict.html",
        "table-cmu_anny_oi_low-stride5_strict-gt_spectral.html",
        "compare-cmu_anny_oi_low.html",
        "meshes-cmu_anny_oi_low.html",
        "model-spectrhums.html",
    } <= pages
    bench = (tmp_path / "site" / "bench-cmu_anny_oi_low.html").read_text()
    assert "Which number to quote" in bench and "stride5_strict</strong>" in bench
    protocol = json.loads((TABLE / "protocol.json").read_text())
    assert protocol["protocol_id"] in bench  # the quoted table's
    table = (tmp_path / "site" / "table-cmu_anny_oi_low-stride5_strict.html").read_text()
    assert "window.ZOO_TABLE" in table
    # nothing is fetched: no script asks the network, no page loads from it
    for script in (tmp_path / "site").rglob("*.js"):
        text = script.read_text()
        assert "fetch(" not in text and "XMLHttpRequest" not in text and "import(" not in text
    for page in (tmp_path / "site").glob("*.html"):
        html = page.read_text()
        loads = re.search(r"<(script|link|img|iframe)[^>]+(src|href)=\"(https?:)?//", html)
        assert loads is None, f"{page.name}: {loads}"


def test_bad_input_is_shown_on_its_page_and_warned(tmp_path):
    results = _copy_results(tmp_path, "cmu_anny_oi_low", "cloth")
    bench = results / "cmu_anny_oi_low"
    shutil.rmtree(bench / "stride5_strict" / "spectrhums")  # a damaged row
    (results / "cloth" / "all" / "summary.json").write_text("{not json")
    empty = results / "cloth" / "all-gt_spectral" / "summary.json"
    empty.write_text(json.dumps(dict(json.loads(empty.read_text()), views=[])))
    (results / "nothing_here").mkdir()
    cards = tmp_path / "cards"
    shutil.copytree(REPO_ROOT / "docs" / "models", cards)
    (cards / "spectrhums_residual.md").unlink()
    build = build_site(tmp_path / "site", results, cards_dir=cards)
    text = "\n".join(build.warnings)
    assert "stride5_strict/spectrhums/results.csv: missing" in text
    assert "cloth/all/summary.json: not readable JSON" in text
    assert "all-gt_spectral/summary.json: the table has no rows" in text
    assert "nothing_here: no table" in text
    assert "spectrhums_residual.md: missing (the model's card)" in text
    site = tmp_path / "site"
    assert (
        "results.csv: missing" in (site / "table-cmu_anny_oi_low-stride5_strict.html").read_text()
    )
    assert "not readable JSON" in (site / "table-cloth-all.html").read_text()
    assert "no rows to show" in (site / "table-cloth-all-gt_spectral.html").read_text()
    assert "no table" in (site / "bench-nothing_here.html").read_text()
    assert "missing (the model" in (site / "model-spectrhums_residual.html").read_text()


def test_malformed_files_are_problems_not_tracebacks(tmp_path):
    results = _copy_results(tmp_path, "cmu_anny_oi_low", "cmu")
    bench = results / "cmu_anny_oi_low"
    summary = bench / "stride5_strict" / "summary.json"
    (results / "cmu" / "all" / "summary.json").write_text("[]")
    stored = json.loads(summary.read_text())
    del stored["views"][0]["models"][0]["bold"]
    summary.write_text(json.dumps(stored))
    nan = bench / "stride5_strict-gt_spectral" / "summary.json"
    nan.write_text(nan.read_text().replace("0.", 'NaN, "x": 0.', 1))
    (results / "cmu" / "ltd8" / "protocol.json").unlink()
    _clips().write(bench / "clips.npz")
    data = (bench / "clips.npz").read_bytes()
    (bench / "clips.npz").write_bytes(data[: len(data) // 2])
    weights = tmp_path / "weights" / "cmu"
    weights.mkdir(parents=True)
    shutil.copy(REPO_ROOT / "weights" / "cmu" / "mlp.safetensors", weights)
    (weights / "mlp.json").write_text(json.dumps({"label": "mlp"}))
    build = build_site(tmp_path / "site", results, weights_root=tmp_path / "weights")
    text = "\n".join(build.warnings)
    assert "cmu/all/summary.json: not readable JSON" in text and "not an object" in text
    assert "views[0].models[0] has no bold" in text
    assert "NaN is no number JSON has" in text
    assert "ltd8/protocol.json: missing" in text
    assert "clips.npz: not a readable clips file" in text
    assert "shipped weights' records cannot be read" in text
    site = tmp_path / "site"
    assert "has no bold" in (site / "table-cmu_anny_oi_low-stride5_strict.html").read_text()
    assert "not a readable clips file" in (site / "bench-cmu_anny_oi_low.html").read_text()
    assert not (site / "meshes-cmu_anny_oi_low.html").exists()


def test_a_card_cannot_run_a_script_or_load_from_the_network(tmp_path):
    results = _copy_results(tmp_path, "cmu_anny_oi_low")
    cards = tmp_path / "cards"
    shutil.copytree(REPO_ROOT / "docs" / "models", cards)
    card = cards / "spectrhums.md"
    card.write_text(
        card.read_text()
        + "\n<script>alert(1)</script>\n\n<img src='https://example.org/x.png'>\n\n"
        "![far](https://example.org/y.png) ![up](../../README.md) [other](mlp.md#recipe)\n"
    )
    build_site(tmp_path / "site", results, cards_dir=cards)
    html = (tmp_path / "site" / "model-spectrhums.html").read_text()
    assert "<script>alert" not in html and "&lt;script&gt;alert(1)&lt;/script&gt;" in html
    assert "&lt;!--" not in html  # the card's comments are not shown
    assert not re.search(r"<img[^>]* src=\"https?:", html)
    assert 'href="model-mlp.html"' in html
    assert not (tmp_path / "site" / "cards" / "README.md").exists()


def test_zoo_site_cli_reports_and_refuses_a_foreign_folder(tmp_path, capsys):
    """The command refuses a folder it did not write in one line; a build, and a second one
    replacing it, succeed. (The zoo's entry point is ``main``: test_cli_conventions.py runs it
    as a process.)"""
    results = _copy_results(tmp_path, "cmu_anny_oi_low")
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    assert main(["site", "--results", str(results), "--out", str(foreign)]) != 0
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "not one the zoo wrote (no .zoo-site)" in err
    assert (foreign / "notes.txt").read_text() == "keep me"
    for _ in range(2):  # a second build replaces the first
        assert main(["site", "--results", str(results), "--out", str(tmp_path / "site")]) == 0
        out = capsys.readouterr().out
        assert "pages to" in out and "index.html" in out


def test_a_model_without_weights_says_where_its_training_stands(tmp_path, capsys):
    """zoo list, the site's index and the model's page: "training: no weights shipped yet",
    with the epochs its paused state has done of those planned (0 of the recipe's without)."""
    weights = tmp_path / "weights"
    shutil.copytree(REPO_ROOT / "weights" / "cmu", weights / "cmu")
    paused = weights / "in_progress" / "cmu" / "auxformer"
    paused.mkdir(parents=True)
    resume = "zoo train --model auxformer --benchmark cmu --seed 0 --resume"
    (paused / "state.json").write_text(
        json.dumps(
            {
                "epochs_run": 3,
                "epochs_planned": 80,
                "best": {"val_mpjpe": 44.125, "epoch": 2},
                "resume": resume,
            }
        )
    )
    status = (
        "training: no weights shipped yet (3 of 80 epochs done; best validation 44.12 mm at "
        f"epoch 2; resume: {resume})"
    )
    unshipped = unshipped_models(load_registry(), weights)
    assert unshipped["auxformer"] == status and "spgsn" not in unshipped and "ltd" not in unshipped
    (tmp_path / "results").mkdir()
    build_site(tmp_path / "site", tmp_path / "results", weights_root=weights)
    assert status in (tmp_path / "site" / "index.html").read_text()
    assert status in (tmp_path / "site" / "model-auxformer.html").read_text()
    assert "spgsn</a>: SPGSN" in (tmp_path / "site" / "index.html").read_text()
    assert main(["list"]) == 0  # the repository's weights: auxformer has none
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("auxformer "))
    assert "training: no weights shipped yet (" in line


def test_the_index_names_the_lowest_row_the_table_shows_and_how_many_are_bold(cmu_site):
    results, site = cmu_site
    index = (site / "index.html").read_text()
    summary = json.loads((results / "cmu" / "all" / "summary.json").read_text())
    view = next(v for v in summary["views"] if v["headline"])
    shown = [m for m in view["models"] if "@" not in m["model"] and not m["floor"]]
    last = len(view["horizons_ms"]) - 1
    best = min(shown, key=lambda m: m["values"][last])
    bold = sum(bool(m["bold"][last]) for m in shown)
    assert f'{best["model"]}<br><span class="num">{best["values"][last]:.2f}</span>' in index
    assert f"{bold - 1} of the other {len(shown) - 1} not distinguishable from it" in index
    assert "@last<br>" not in index


def test_the_compare_page_says_which_model_is_lower_in_the_tables_digits(cmu_site):
    """ltd against repeat_last at 720 ms on ltd8: the interval includes 0 (few windows a
    recording), so no verdict; the page says that is the rule, and that ltd is lower."""
    import html as html_lib

    results, site = cmu_site
    page = html_lib.unescape((site / "compare-cmu.html").read_text())
    summary = json.loads((results / "cmu" / "ltd8" / "summary.json").read_text())
    pair = next(c for c in summary["comparisons"] if (c["a"], c["b"]) == ("ltd", "repeat_last"))
    row = next(r for r in pair["rows"] if r["verdict"] == "none")
    assert f"{row['a']:.2f}" in page and f"{row['b']:.2f}" in page  # the tables' digits
    assert (
        f"not separated: the interval includes 0 (ltd lower here by {-row['difference']:.2f})"
        in page
    )
    assert "no difference detectable" not in page
    # every other pair is on the page too, hidden until picked (site.js, tested in a browser)
    assert (
        '<section class="pair" data-table="all" data-a="spgsn" data-b="spgsn_1body" '
        'data-reader="no" hidden>' in page
    )


@pytest.mark.parametrize("table", ["cmu/all", "cloth/all"])
def test_every_two_predictions_of_a_table_are_compared_once_the_readers_first(table):
    """spgsn against its ablation spgsn_1body, or any other two rows: a floor (the autoencoder
    seeing the future) and the ground truth are no prediction and pair with nothing."""
    from itertools import combinations

    from zoo.stats.ranking import is_floor

    summary = json.loads((RESULTS / table / "summary.json").read_text())
    rows = sorted(
        m["model"]
        for m in summary["views"][0]["models"]
        if not is_floor(m["model"]) and m["model"] != "ground_truth"
    )
    pairs = [(c["a"], c["b"]) for c in summary["comparisons"]]
    assert sorted(map(frozenset, pairs), key=sorted) == sorted(
        map(frozenset, combinations(rows, 2)), key=sorted
    )
    readers = [c["reader"] for c in summary["comparisons"]]
    assert readers == sorted(readers, reverse=True) and any(readers)  # the readers' first
    if table == "cmu/all":
        assert ("spgsn", "spgsn_1body") in pairs and not readers[
            pairs.index(("spgsn", "spgsn_1body"))
        ]


def test_a_row_trained_short_of_its_recipe_says_so_where_its_number_is(tmp_path):
    """A shipped run that capped its epochs at 50 batches (as SPGSN's first weights did, 22% of
    the recipe's windows): its rows carry a note in the table's data; a record with the epoch's
    window count gives the share; a full run gives none."""
    from zoo.report.cards import Shipped, budget_note, short_training_notes

    results = _copy_results(tmp_path, "cmu")
    weights = tmp_path / "weights"
    shutil.copytree(REPO_ROOT / "weights" / "cmu", weights / "cmu")
    build_site(tmp_path / "full", results, weights_root=weights)
    assert "its run saw" not in (tmp_path / "full" / "table-cmu-all.html").read_text()
    short = json.loads((weights / "cmu" / "spgsn@last.json").read_text())
    short["max_batches"], short["training"]["samples_seen"] = 50, 161_920
    (weights / "cmu" / "spgsn@last.json").write_text(json.dumps(short))
    build_site(tmp_path / "site", results, weights_root=weights)
    page = (tmp_path / "site" / "table-cmu-all.html").read_text()
    assert '"spgsn@last":"its run saw 23% of its recipe\'s training windows (161,920' in page
    record = {
        "training": {"samples_seen": 161_920},
        "validation": {"training_windows": 14_389},
        "recipe": {"batch_size": 32},
    }
    assert budget_note(50, **record) == (
        "its run saw 23% of its recipe's training windows (161,920 of 718,400)"
    )
    record["training"]["samples_seen"] = 718_400
    assert budget_note(50, **record) is None
    full = weights_record("ltd", label="ltd@last", **record)
    shipped = {"ltd": [Shipped("ltd@last", ("cmu",), Path(), full)]}
    assert short_training_notes(load_registry(), shipped) == {}


def test_a_model_page_shows_its_card_once_and_every_horizon(cmu_site):
    _, site = cmu_site
    page = (site / "model-spgsn.html").read_text()
    assert page.count("<h1>") == 1  # the page's title, not the card's again
    assert "<h2>Rows</h2>" not in page and "<h2>Training curve</h2>" not in page
    assert "<h2>Hyper-parameters</h2>" in page and "<h2>Architecture</h2>" in page
    assert 'class="num wrap"' in page and "1000: " in page
    # its paper, its authors' code and the BibTeX of its paper, once (not again in the card)
    assert '<a href="https://arxiv.org/abs/2208.00368" rel="noopener noreferrer">Paper</a>' in page
    assert '<a href="https://github.com/MediaBrain-SJTU/SPGSN"' in page
    assert page.count("@inproceedings{li2022skeleton,") == 1


def test_a_run_stopped_by_its_patience_is_not_short_and_a_tiny_split_does_not_crash():
    from zoo.report.cards import budget_note

    run = {
        "training": {"samples_seen": 25 * 14_368, "epochs_run": 25, "best": {"epoch": 15}},
        "validation": {"training_windows": 14_389},
        "recipe": {"batch_size": 16, "epochs": 58, "patience": 10},
    }
    assert budget_note(58, **run) is None  # finished by its recipe's patience
    run["recipe"]["patience"] = None
    assert budget_note(58, **run).startswith("its run saw")
    run["validation"]["training_windows"] = 3  # fewer windows than a batch
    assert budget_note(58, **run) is None or "training windows" in budget_note(58, **run)


def test_a_model_being_retrained_says_so_beside_its_shipped_rows(tmp_path):
    weights = tmp_path / "weights"
    shutil.copytree(REPO_ROOT / "weights" / "cmu", weights / "cmu")
    paused = weights / "in_progress" / "cmu" / "spgsn"
    paused.mkdir(parents=True)
    summary = {
        "epochs_run": 6,
        "epochs_planned": 50,
        "finished": False,
        "best": {"val_mpjpe": 41.234, "epoch": 5},
        "resume": "zoo train --model spgsn --benchmark cmu --seed 0 --resume",
    }
    (paused / "state.json").write_text(json.dumps(summary))
    status = unshipped_models(load_registry(), weights)["spgsn"]
    # the queue's line, as a model with no weights shows it: progress, best, how to resume
    assert status.startswith(
        "retraining: 6 of 50 epochs done; best validation 41.23 mm at epoch 5; resume: zoo "
        "train --model spgsn --benchmark cmu --seed 0 --resume (its rows are"
    )
    (paused / "state.json").write_text(json.dumps({**summary, "finished": True}))
    assert "spgsn" not in unshipped_models(load_registry(), weights)
