"""Model cards (zoo.report.cards): the committed cards match their sources, and a card goes stale
when a shipped record changes; regenerating keeps what was written by hand."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from tiny_models import weights_record

from zoo.cli import main
from zoo.paths import REPO_ROOT
from zoo.report.cards import CARDS_DIR, END_MARKER, CardError, build_cards

WEIGHTS = REPO_ROOT / "weights"


def test_committed_cards_are_up_to_date():
    statuses = build_cards(write=False)
    stale = [f"{s.name}: {s.reason}" for s in statuses if not s.fresh]
    assert not stale, f"stale model cards (run `zoo cards`): {stale}"
    # one card per model with shipped weights, each with its hand-written part
    shipped = {json.loads(p.read_text())["model"] for p in WEIGHTS.glob("*/*.json")}
    assert shipped <= {s.name for s in statuses}
    for s in statuses:
        if s.name == "README":  # the index, all generated
            continue
        hand = s.path.read_text().split(END_MARKER, 1)[1]
        assert hand.strip(), f"{s.path}: nothing written by hand below the marker"


def _copy_weights(tmp_path: Path, *benchmarks: str) -> Path:
    """The shipped weights of some benchmarks: tensors linked, records copied (to be edited), and
    a link between benchmarks (cmu50's to cmu's) kept a link, so an edit shows in both."""
    root = tmp_path / "weights"
    for benchmark in benchmarks:
        (root / benchmark).mkdir(parents=True)
        for path in (WEIGHTS / benchmark).iterdir():
            target = root / benchmark / path.name
            if path.is_symlink() and path.suffix == ".json":
                target.symlink_to(path.readlink())
                assert target.resolve().is_relative_to(root), f"{path} links out of {benchmarks}"
            elif path.suffix == ".json":
                shutil.copy(path, target)
            else:
                target.symlink_to(path.resolve())
    return root


@pytest.mark.slow  # out of the README test command's 2 minutes; .ci/run runs it after
def test_a_changed_record_makes_its_card_stale_and_a_rebuild_keeps_the_hand_written_part(
    tmp_path, capsys
):
    # cmu50's rows read cmu's weights through links, so the cards list both benchmarks
    weights = _copy_weights(tmp_path, "cmu", "cmu50")
    cards = tmp_path / "cards"
    shutil.copytree(CARDS_DIR, cards)
    fresh = {s.name: s.fresh for s in build_cards(cards, weights_root=weights, write=False)}
    assert fresh["spgsn"] and fresh["mlp"]

    record_path = weights / "cmu" / "spgsn@last.json"
    record = json.loads(record_path.read_text())
    record["training"]["seconds"] += 3600  # a budget recorded differently
    record_path.write_text(json.dumps(record))
    minutes = f"| {record['training']['seconds'] / 60:.0f} |"  # as the card's table prints them
    statuses = {s.name: s for s in build_cards(cards, weights_root=weights, write=False)}
    assert not statuses["spgsn"].fresh
    assert statuses["spgsn"].reason == "out of date with its sources"
    assert statuses["mlp"].fresh

    rc = main(["cards", "--check", "--out", str(cards), "--weights", str(weights), "--readme", ""])
    out = capsys.readouterr().out
    assert rc == 1
    assert "spgsn.md: out of date with its sources" in out
    assert minutes in out  # the new minutes in the diff it prints

    hand = (cards / "spgsn.md").read_text().split(END_MARKER, 1)[1]
    rc = main(["cards", "--out", str(cards), "--weights", str(weights), "--readme", ""])
    assert rc == 0
    text = (cards / "spgsn.md").read_text()
    assert text.split(END_MARKER, 1)[1] == hand
    assert minutes in text
    # a generated card whose model has no weights, figures or rows any more: reported, kept
    shutil.copy(cards / "mlp.md", cards / "retired.md")
    after = build_cards(cards, weights_root=weights, write=False)
    orphans = {s.name for s in after if s.reason == "no shipped weights or published figures"}
    assert orphans == {"retired"}
    assert (cards / "retired.md").is_file()
    # only CMU's weights were copied (cmu, cmu50); mesh-only entries keep their cards by rows
    names = {s.name for s in after}
    assert {"spectrhums_anchored", "spectrhums_residual", "spectrhums_residual_anchored"} <= names
    assert all(s.fresh for s in after if s.name not in orphans)


def test_a_card_without_its_end_marker_is_refused(tmp_path):
    cards = tmp_path / "cards"
    shutil.copytree(CARDS_DIR, cards)
    weights = _copy_weights(tmp_path, "cmu")
    record_path = weights / "cmu" / "mlp@last.json"
    record = json.loads(record_path.read_text())
    record["seed"] = 1
    record_path.write_text(json.dumps(record))
    (cards / "mlp.md").write_text("# mlp\n\nedited by hand, marker lost\n")
    with pytest.raises(CardError, match="mlp.md: no end marker"):
        build_cards(cards, weights_root=weights)


def test_a_card_sets_its_rows_against_the_paper_per_action_under_the_same_protocol():
    from zoo.evaluation.results import read_table
    from zoo.protocol.published import load_published

    paper = next(p for p in load_published() if p.label == "spgsn (reported)")
    frame = read_table(REPO_ROOT / "results" / "cmu" / "all").frame
    mine = frame[
        (frame["model"] == "spgsn")
        & (frame["metric"] == "mpjpe")
        & (frame["joints"] == "all38")
        & (frame["averaging"] == "frame")
        & (frame["horizon_ms"] == 80)
    ].set_index("action")["value"]
    actions = list(paper.per_action)
    card = (CARDS_DIR / "spgsn.md").read_text()
    block = card.split("`spgsn` over **spgsn (reported)**", 1)[1].split("\n\n", 2)[1]
    lines = {row.split("|")[1].strip(): row.split("|")[2].strip() for row in block.splitlines()[2:]}
    for action in actions:
        assert lines[action] == f"{mine[action] / paper.per_action[action][80]:.2f}"
    mean = sum(mine[a] for a in actions) / sum(paper.per_action[a][80] for a in actions)
    assert lines[f"mean of {len(actions)}"] == f"{mean:.2f}"


def test_a_card_counts_every_stage_its_weights_were_trained_on_from():
    """Weights trained on from another checkpoint (``--init-from``) name each earlier stage's
    budget and what it set differently; the budget table holds the last stage only."""
    from zoo.report.cards import Shipped, _earlier_stage_lines

    def stage(epochs, samples, seconds, ae, sampler, before=None):
        return {
            "kind": "checkpoint",
            "path": f"checkpoints/stage{epochs}/last.pt",
            "sha256": "ab" * 32,
            "hparams": {"autoencoder_epochs": ae, "latent": 256},
            "recipe": {"batch_size": 32, "val_sampler": sampler},
            "training": {"epochs_run": epochs, "samples_seen": samples, "seconds": seconds},
            "init_from": before,
        }

    record = weights_record(
        hparams={"autoencoder_epochs": 2, "latent": 256},
        init_from=stage(22, 64768, 600.0, 22, "stride5_strict", stage(3, 3200, 60.0, 3, "")),
    )
    lines = _earlier_stage_lines(
        [Shipped("m", ("x",), REPO_ROOT / "weights/x/m.safetensors", record)]
    )
    assert len(lines) == 3 and lines[-1] == ""
    assert lines[0].startswith("- `weights/x/m.safetensors` was trained on from `checkpoints/")
    assert "22 epochs, 2,024 optimizer steps, 64,768 samples, 10 min" in lines[0]
    assert "`autoencoder_epochs: 22`" in lines[0] and "latent" not in lines[0]
    assert "validated on `stride5_strict` windows" in lines[0]
    assert ": before that, from `checkpoints/stage3/last.pt`" in lines[1]
    assert "3 epochs, 100 optimizer steps" in lines[1] and "`autoencoder_epochs: 3`" in lines[1]
    assert (
        _earlier_stage_lines([Shipped("m", ("x",), REPO_ROOT / "m.safetensors", weights_record())])
        == []
    )
