"""Cost columns on demand: only ``zoo costs`` measures them (float32, time-boxed) into
``costs.json``; ``zoo leaderboard`` shows what is stored, naming the machine, and measures
nothing."""

import json
import time
from datetime import datetime, timezone
from pathlib import Path

import pandas as pd
import pytest
import torch
from test_leaderboard import cmu_and_registry, trained_tiny

import zoo.leaderboard.costs
import zoo.leaderboard.efficiency
from zoo.cli import main
from zoo.leaderboard.efficiency import LATENCY_REPEATS, TRAINING_STEPS, measure
from zoo.leaderboard.plan import Plan
from zoo.leaderboard.rebuild import regenerate
from zoo.models.recipe import DEFAULT_RECIPE
from zoo.train.step import forward_precision


def files(folder: Path) -> dict[Path, bytes]:
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def rows_and_results(table: Path) -> dict[Path, bytes]:
    """A table's results.csv and every row folder: what re-rendering costs never touches."""
    return {
        name: data
        for name, data in files(table).items()
        if name.parts[0] == "results.csv" or len(name.parts) > 1
    }


def headline_cells(board: str, label: str) -> list[str]:
    headline = board.split("\n## MPJPE")[0]
    line = next(x for x in headline.splitlines() if x.startswith(f"| {label} "))
    return [cell.strip() for cell in line.strip("|").split("|")]


def no_measuring(*args, **kwargs):
    raise AssertionError("zoo leaderboard measured a cost")


def test_costs_are_measured_only_by_zoo_costs_and_shown_with_their_machine(
    tmp_path, monkeypatch, capsys
):
    root, registry, checkpoints = trained_tiny(tmp_path)
    out = tmp_path / "results"
    monkeypatch.setattr(zoo.leaderboard.efficiency, "measure", no_measuring)
    monkeypatch.setattr(zoo.leaderboard.costs, "measure", no_measuring)
    # An older costs.json (timings in each recipe's precision) is not read, and not rewritten.
    old = {"entries": {"0123": {"key": {"machine": "elsewhere"}, "costs": {"parameters": 1}}}}
    (out / "cmu").mkdir(parents=True)
    (out / "cmu" / "costs.json").write_text(json.dumps(old))
    regenerate("cmu", registry=registry, data_root=root, out_root=out, checkpoints=checkpoints)
    assert "costs.json: an older format" in capsys.readouterr().err
    assert json.loads((out / "cmu" / "costs.json").read_text()) == old
    board = (out / "cmu" / "all" / "leaderboard.md").read_text()
    assert headline_cells(board, "tiny")[-4:] == [""] * 4  # no cost stored: empty cells
    assert "Empty cost cells (repeat_last, tiny)" in board
    assert "`zoo costs --benchmark cmu` fills them" in board
    assert not (out / "cmu" / "all" / "efficiency.csv").exists()
    # a table written before zoo costs named its machine inside the paragraph above the table
    legacy = (
        ". Costs measured once per architecture on CPU Old, 2 threads: parameters; latency; "
        "training windows per second (forward, backward, clip and Adam at the recipe's batch "
        "size and precision)."
    )
    lines = board.split("\n")
    at = next(i for i, line in enumerate(lines) if line.startswith("± is half"))
    lines[at] = lines[at][:-1] + legacy
    (out / "cmu" / "all" / "leaderboard.md").write_text("\n".join(lines))

    # zoo costs: every row measured once per architecture, in float32, beside the machine.
    monkeypatch.undo()
    common = [
        "--registry",
        str(tmp_path / "registry.yaml"),
        "--data-root",
        str(root),
        "--out",
        str(out),
        "--checkpoints",
        str(checkpoints),
        "--weights",
        str(tmp_path / "weights"),
    ]
    tables = [out / "cmu" / "all", out / "cmu" / "ltd8"]
    before = {table: rows_and_results(table) for table in tables}
    assert main(["costs", "--benchmark", "cmu", "--seconds", "5", *common]) == 0
    captured = capsys.readouterr()
    assert "cmu [1/2] repeat_last: measuring in float32" in captured.err
    assert "cmu [2/2] tiny: training" in captured.err and "older format" in captured.err
    stored = json.loads((out / "cmu" / "costs.json").read_text())
    assert stored["version"] == 2 and set(stored["rows"]) == {"tiny", "repeat_last"}
    tiny = stored["rows"]["tiny"]
    today = datetime.now(timezone.utc).date().isoformat()
    assert tiny["precision"] == "float32" and tiny["date"] == today
    assert tiny["device"].startswith("CPU ") and tiny["threads"] == torch.get_num_threads()
    assert tiny["parameters"] == 10 * 16 + 16 + 16 * 25 + 25
    assert tiny["train_samples_per_s"] > 0 and 1 <= tiny["training_steps"] <= TRAINING_STEPS
    assert stored["rows"]["repeat_last"]["train_samples_per_s"] is None
    for table in tables:  # only the cost columns were re-rendered
        assert rows_and_results(table) == before[table]
    board = (out / "cmu" / "all" / "leaderboard.md").read_text()
    assert headline_cells(board, "tiny")[-4:-1] == [
        "0.001 M",
        f"{tiny['gflop_per_sample']:.3g}",
        f"{tiny['latency_ms']:.3g}",
    ]
    assert f"Costs measured by `zoo costs` on {tiny['device']} ({today})" in board
    assert "every model in float32" in board and "Empty cost cells" not in board
    assert "CPU Old" not in board
    efficiency = pd.read_csv(out / "cmu" / "all" / "efficiency.csv")
    assert list(efficiency.model) == ["repeat_last", "tiny"]
    assert set(efficiency.precision) == {"float32"}
    counts = f",float32,{tiny['latency_repeats']},{tiny['training_steps']},"  # integers
    assert counts in (out / "cmu" / "all" / "efficiency.csv").read_text()
    assert "## cmu" in (out / "README.md").read_text()

    # zoo leaderboard, here or on another machine: it measures nothing and rewrites nothing...
    monkeypatch.setattr(zoo.leaderboard.efficiency, "measure", no_measuring)
    monkeypatch.setattr(zoo.leaderboard.costs, "measure", no_measuring)
    monkeypatch.setattr(zoo.leaderboard.efficiency, "device_name", lambda device: "CPU Another")
    written = files(out)
    mtimes = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}
    regenerate("cmu", registry=registry, data_root=root, out_root=out, checkpoints=checkpoints)
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()} == mtimes
    # ...and a rebuilt table shows the stored costs, under the machine that measured them.
    regenerate(
        "cmu",
        registry=registry,
        data_root=root,
        out_root=out,
        checkpoints=checkpoints,
        plan=Plan(recompute=True),
    )
    for table in ("all", "ltd8"):  # zoo costs wrote what a rebuild writes, and no more
        for name in ("leaderboard.md", "efficiency.csv"):
            assert files(out)[Path("cmu", table, name)] == written[Path("cmu", table, name)]
    assert files(out)[Path("cmu/costs.json")] == written[Path("cmu/costs.json")]
    assert "Another" not in (out / "cmu" / "all" / "leaderboard.md").read_text()


def test_costs_refuses_a_benchmark_without_tables(tmp_path, capsys):
    root, _ = cmu_and_registry(tmp_path)
    args = ["costs", "--benchmark", "cmu", "--data-root", str(root), "--out", str(tmp_path)]
    assert main(args) == 2
    assert "no committed table (zoo leaderboard --benchmark cmu makes them)" in (
        capsys.readouterr().err
    )
    assert main([*args, "--seconds", "0"]) == 2
    assert "--seconds 0: expected a positive time budget" in capsys.readouterr().err


SEEN: list[torch.dtype] = []  # the dtype of every forward's product (copies of a model too)


class Recorder(torch.nn.Module):
    def __init__(self, sleep: float = 0.0):
        super().__init__()
        self.layer = torch.nn.Linear(10 * 5 * 3, 25 * 5 * 3)
        self.sleep = sleep

    def forward(self, history):
        time.sleep(self.sleep)
        out = self.layer(history.flatten(1))
        SEEN.append(out.dtype)
        return out.reshape(len(history), 25, 5, 3)


def test_a_bfloat16_recipe_is_timed_in_float32():
    SEEN.clear()
    model = Recorder()
    with forward_precision("bfloat16", "cpu"):  # what training in its recipe would compute in
        model(torch.zeros(2, 10, 5, 3))
    assert SEEN == [torch.bfloat16]
    SEEN.clear()
    recipe = {"batch_size": 4, "grad_clip": 1.0, "precision": "bfloat16"}
    row = measure(model, input_frames=10, output_frames=25, points=5, recipe=recipe)
    assert row["precision"] == "float32" and row["train_samples_per_s"] > 0
    assert row["training_steps"] == TRAINING_STEPS and SEEN and set(SEEN) == {torch.float32}


def test_a_slow_model_gets_fewer_repeats_within_its_budget():
    said = []
    row = measure(
        Recorder(sleep=0.05),
        input_frames=10,
        output_frames=25,
        points=5,
        recipe={"batch_size": 2},
        seconds=0.2,
        say=said.append,
    )
    # each call takes at least 0.05 s: a quarter of the budget (0.05 s) holds one timed call,
    # and the one that runs over it; the steps get what is left of 0.2 s after that
    assert row["latency_repeats"] <= 2 < LATENCY_REPEATS
    assert row["training_steps"] <= 2 < TRAINING_STEPS
    assert any(f"(not {LATENCY_REPEATS}: time budget of 0.2 s)" in text for text in said)
    assert any(f"(not {TRAINING_STEPS}: time budget of 0.2 s)" in text for text in said)
    unboxed = measure(Recorder(), input_frames=10, output_frames=25, points=5)
    assert unboxed["latency_repeats"] == LATENCY_REPEATS and unboxed["training_steps"] is None


@pytest.mark.parametrize("epochs, phase", [(3, "joint"), (2, "autoencoder")])
def test_a_phased_model_is_timed_in_the_phase_its_recipe_ends_in(monkeypatch, epochs, phase):
    # SpecTrHuMS is built in its autoencoder phase (autoencoder_epochs 2) and the engine moves it
    # to the joint phase (the transformer trains too: a step many times dearer) from epoch 2 on
    from test_spectrhums import T_IN, T_OUT, V, make

    from zoo.models.spectrhums import SpecTrHuMS

    timed = []
    terms = SpecTrHuMS.coefficient_loss_terms

    def recorded(self, coeffs):
        timed.append(self.phase)
        return terms(self, coeffs)

    monkeypatch.setattr(SpecTrHuMS, "coefficient_loss_terms", recorded)
    model = make(autoencoder_epochs=2)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    recipe = {"batch_size": 4, "grad_clip": 1.0, "epochs": epochs}
    row = measure(model, input_frames=T_IN, output_frames=T_OUT, points=V, recipe=recipe)
    assert row["training_steps"] == TRAINING_STEPS and row["train_samples_per_s"] > 0
    assert timed == [phase] * (TRAINING_STEPS + 1)  # the warm-up step and the timed ones
    assert model.phase == "autoencoder"  # a copy was stepped, the model is as it was
    assert all(torch.equal(v, before[k]) for k, v in model.state_dict().items())


class Phased(Recorder):
    """A model whose training-engine hook sees frames, not a training view."""

    def start_epoch(self, epoch, frames):
        CALLS.append((epoch, [(tuple(f.shape), counts.tolist()) for f, counts in frames()]))

    def forward(self, history):
        if self.training:
            CALLS.append("step")
        return super().forward(history)


CALLS: list = []


@pytest.mark.parametrize("recipe, epoch", [({"epochs": 7}, 6), ({}, DEFAULT_RECIPE["epochs"] - 1)])
def test_a_model_without_a_training_view_gets_its_last_epoch_on_the_windows_frames(recipe, epoch):
    CALLS.clear()
    measure(Phased(), input_frames=10, output_frames=25, points=5, recipe={"batch_size": 2,
            **recipe})  # fmt: skip
    # before any step: the recipe's last epoch (the engine's default epochs where it gives
    # none), every frame of the timed windows (2 windows of 35 frames) once, counted once
    assert CALLS == [(epoch, [((70, 5, 3), [1] * 70)])] + ["step"] * (TRAINING_STEPS + 1)


@pytest.mark.parametrize("version", [None, 2])
def test_costs_file_of_another_format_is_not_read(tmp_path, version):
    from zoo.leaderboard.efficiency import Costs

    path = tmp_path / "costs.json"
    entry = {"architecture": "a" * 16, "parameters": 3, "precision": "float32"}
    data = {"version": 2, "rows": {"m": entry}} if version else {"entries": {"x": {}}}
    path.write_text(json.dumps(data))
    costs = Costs(path)
    assert costs.old == (version is None)
    expected = {"parameters": 3, "precision": "float32"} if version else None
    assert costs.get("m", "a" * 16) == expected
    assert costs.get("m", "b" * 16) is None  # another architecture's costs: not shown


def test_costs_of_some_models_skip_the_benchmarks_without_their_rows(tmp_path, monkeypatch, capsys):
    """`zoo costs --model M` over every committed benchmark measures where M has rows and
    says which it skipped; a benchmark named with --benchmark must have them."""
    for name in ("cmu", "cloth"):
        (tmp_path / name / "all").mkdir(parents=True)
        (tmp_path / name / "all" / "results.csv").write_text("model\n")
    measured = []

    def measure_costs(bench, *, models, **options):
        if bench == "cmu":
            raise zoo.leaderboard.costs.NoRowsError(
                f"{bench}: no row of {', '.join(models)} in its tables"
            )
        measured.append(bench)

    monkeypatch.setattr(zoo.leaderboard.costs, "measure_costs", measure_costs)
    monkeypatch.setattr("zoo.report.outputs.write_index", lambda root: root / "README.md")
    monkeypatch.setattr(
        "zoo.cli.costs.committed_benchmarks", lambda root: ["cmu", "cloth"], raising=True
    )
    assert main(["costs", "--model", "spectrhums", "--results", str(tmp_path)]) == 0
    assert measured == ["cloth"]
    assert "cmu: no row of spectrhums in its tables: skipped" in capsys.readouterr().err
    assert main(["costs", "--model", "spectrhums", "--benchmark", "cmu"]) == 2
    assert "cmu: no row of spectrhums in its tables" in capsys.readouterr().err


def test_costs_of_a_model_without_rows_anywhere_is_one_line(tmp_path, capsys):
    """On real tables: a model with no row in any committed table skips each benchmark and
    ends in one error line."""
    root, registry = cmu_and_registry(tmp_path)
    out = tmp_path / "results"
    regenerate("cmu", registry=registry, data_root=root, out_root=out)
    capsys.readouterr()
    args = ["costs", "--model", "tiny", "--results", str(out), "--data-root", str(root)]
    assert main([*args, "--registry", str(tmp_path / "registry.yaml")]) == 2
    err = capsys.readouterr().err
    assert "cmu: no row of tiny in its tables: skipped" in err
    assert f"no table under {out} has a row of tiny" in err
