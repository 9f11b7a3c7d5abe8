"""The README's headline tables quote results/: every number there equals the committed table's,
printed as the tables print it, and every row the README names exists."""

from __future__ import annotations

import re
import shutil

from zoo.evaluation.markdown import metric_unit
from zoo.evaluation.results import read_table
from zoo.paths import REPO_ROOT

BLOCK = re.compile(r"<!-- headline (\S+)/(\S+) (\S+) (\S+) -->\n(.*?)<!-- end headline -->", re.S)


def test_readme_headline_numbers_are_the_committed_ones():
    text = (REPO_ROOT / "README.md").read_text()
    blocks = BLOCK.findall(text)
    assert len(blocks) >= 2, "the README's headline tables lost their markers"
    for bench, table, metric, joints, body in blocks:
        frame = read_table(REPO_ROOT / "results" / bench / table).frame
        frame = frame[
            (frame["action"] == "average")
            & (frame["metric"] == metric)
            & (frame["joints"] == joints)
            & (frame["averaging"] == "frame")
        ]
        lines = [line for line in body.strip().splitlines() if line.startswith("|")]
        horizons = [int(h.strip().removesuffix(" ms")) for h in lines[0].strip("|").split("|")[1:]]
        fmt = metric_unit(metric)[1]
        for line in lines[2:]:
            model, *cells = [c.strip() for c in line.strip("|").split("|")]
            values = frame[frame["model"] == model].set_index("horizon_ms")["value"]
            assert len(values), f"README: {bench}/{table} has no row {model!r}"
            for horizon, cell in zip(horizons, cells):
                assert cell == format(values[horizon], fmt), (
                    f"README: {bench}/{table} {model} at {horizon} ms says {cell}, "
                    f"its rows' results.csv {format(values[horizon], fmt)}"
                )


def test_zoo_cards_rewrites_a_stale_headline(tmp_path, capsys):
    """The README's headline tables are generated: a number edited by hand is found stale by
    ``zoo cards --check`` and put back by ``zoo cards``."""
    from zoo.cli import main

    readme = tmp_path / "README.md"
    text = (REPO_ROOT / "README.md").read_text()
    block = BLOCK.search(text)
    row = [line for line in block.group(5).splitlines() if line.startswith("|")][2]
    model, first, *rest = [c.strip() for c in row.strip("|").split("|")]
    edited = "| " + " | ".join([model, "0.00", *rest]) + " |"
    assert edited != row
    readme.write_text(text.replace(row, edited))
    out = tmp_path / "cards"  # the committed cards, current: only the README is rewritten
    shutil.copytree(REPO_ROOT / "docs" / "models", out)
    argv = ["cards", "--out", str(out), "--readme", str(readme)]
    assert main([*argv, "--check"]) == 1
    stale = [line for line in capsys.readouterr().out.splitlines() if "up to date" not in line]
    assert stale[0].startswith(f"{readme}: ")  # the README alone: one stale, then its diff
    assert stale[-1].startswith("1 of ") and "card(s) stale" in stale[-1]
    assert main(argv) == 0
    assert readme.read_text() == text


def test_the_readmes_table_picture_shows_the_committed_numbers():
    """docs/site/table-cmu.png is taken by the browser tests from the committed results
    (ZOO_SITE_SCREENSHOTS=docs/site), which write the numbers it shows beside it: they must be
    the committed table's, or the picture is stale."""
    import json

    assert "docs/site/table-cmu.png" in (REPO_ROOT / "README.md").read_text()
    pictured = json.loads((REPO_ROOT / "docs" / "site" / "table-cmu.json").read_text())
    summary = json.loads((REPO_ROOT / pictured["table"] / "summary.json").read_text())
    view = summary["views"][0]  # the view a table page opens on
    stored = {m["model"]: dict(zip(view["horizons_ms"], m["values"])) for m in view["models"]}
    assert pictured["rows"], "no row pictured"
    stale = [
        f"{model} at {h} ms: pictured {value}, committed {stored.get(model, {}).get(int(h))}"
        for model, cells in pictured["rows"].items()
        for h, value in cells.items()
        if stored.get(model, {}).get(int(h)) != value
    ]
    assert not stale, "the README's picture is stale: " + "; ".join(stale[:5])
