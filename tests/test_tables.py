"""What the committed tables rank: rows that are no prediction (an autoencoder floor, the ground
truth's own MELV, a held frame's MELV of 0 by construction) are neither ranked nor bold."""

import json

from zoo.paths import REPO_ROOT


def test_rows_that_are_no_prediction_are_neither_ranked_nor_bold():
    held_frame_melv = 0
    for path in sorted((REPO_ROOT / "results").glob("*/*/summary.json")):
        for view in json.loads(path.read_text())["views"]:
            for row in view["models"]:
                reference = (
                    row["floor"]
                    or row["model"] == "ground_truth"
                    or all(v == 0 for v in row["values"])
                )
                assert row["unranked"] == reference, (path, view["metric"], row["model"])
                assert not (reference and any(row["bold"])), (path, row["model"])
                assert not (reference and row["model"] in view["best"]), (path, row["model"])
                held_frame_melv += view["metric"] == "melv" and row["model"] == "repeat_last"
    assert held_frame_melv >= 20  # every mesh table's MELV views hold it


def test_a_row_trained_short_and_timings_of_two_machines_are_marked_where_the_number_is():
    """SpecTrHuMS's weights on CMU-on-Anny saw a run short of its recipe; CMU's costs came
    from two machines. Re-rendering the cost cells (zoo costs) keeps both marks and every other
    byte; SPGSN's rows, trained to their recipe since, carry no mark."""
    from zoo.leaderboard.efficiency import Costs
    from zoo.report.tables import with_costs

    path = REPO_ROOT / "results" / "cmu" / "all" / "leaderboard.md"
    text = path.read_text()
    rows: dict[str, list[str]] = {}  # the headline's, the first table of the page
    for line in text.split("## Headline")[1].split("\n\n")[2].splitlines()[2:]:
        cells = [c.strip() for c in line.split("|")[1:-1]]
        rows[cells[0]] = cells
    assert "spgsn" in rows and "spgsn@last" in rows and "ltd" in rows
    assert "Trained short of its recipe" not in text
    short = (REPO_ROOT / "results/cmu_anny_oi_low/stride5_strict/leaderboard.md").read_text()
    assert "| spectrhums † " in short and "† Trained short of its recipe" in short
    assert "(../../../docs/models/spectrhums.md)" in short
    # each cell carries its machine's letter, which the legend names (letters follow the dates)
    letters = {m: rows[m][-2].rsplit(" ", 1)[1] for m in ("pgbig", "ltd")}
    assert letters["pgbig"] != letters["ltd"]
    assert all(f"{letter} CPU " in text for letter in letters.values())
    assert "(a) CPU AMD EPYC" in text and "timings of different machines are not comparable" in text
    costs = Costs(REPO_ROOT / "results" / "cmu" / "costs.json").rows
    efficiency = {
        label: {k: v for k, v in row.items() if k != "architecture"} for label, row in costs.items()
    }
    labels = [label for label in rows if "(reported" not in label]
    assert with_costs(text, labels, efficiency, "cmu") == text
    machine = rows["spgsn"][-2].rsplit(" ", 1)[1]  # "(c)": the letter of its machine
    efficiency["spgsn"] = dict(efficiency["spgsn"], latency_ms=99.0)
    again = with_costs(text, labels, efficiency, "cmu")
    assert next(line for line in again.splitlines() if line.startswith("| spgsn ")).count(
        f"99 {machine}"
    )
