"""Issue 29's ablation of SpecTrHuMS recipes: train its arms, then score them.

Every arm's main stage has the same budget (steps, batch, data, validation split, seed); arms C
and D add an autoencoder-only first stage (cheap: arm A's autoencoder-only epochs took 50 s for
92 steps and a validation, its joint ones 200-400 s, one thread), which the budget column
counts.

The arms, their budget and the validation split are data (``spectrhums_29.yaml`` beside this
file). ``train ARM [--seed S]`` runs ``zoo train`` for one arm and seed into its own folder,
resuming where a previous run stopped. ``score`` scores every trained arm, with the paper's
inference and anchored, on the validation recordings its checkpoint names (normalised vertex
RMSE at the first frame, 80, 400 and 1000 ms, mean vertex error) and on the benchmark's test
windows (RMSE, frame averaging, mean over actions), beside repeat-last on the same windows, and
prints a markdown table with each arm's budget (steps, samples, minutes, device).

    python benchmarks/ablation/spectrhums.py train A
    python benchmarks/ablation/spectrhums.py score > table.md

``--benchmark NAME`` runs an arm's recipe on another mesh benchmark (how the winner is trained
where it ships), its runs under ``<out>/<NAME>/``, at the same epochs unless the config's
``per_benchmark`` gives NAME its own (budget, samplers).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import yaml

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
TEST_HORIZONS_MS = (40, 80, 160, 400, 1000)


def load_config(path: Path) -> dict:
    cfg = yaml.safe_load(path.read_text())
    for key in ("benchmark", "out", "seeds", "train_set", "max_batches", "arms"):
        if key not in cfg:
            raise SystemExit(f"{path}: field {key!r} is required")
    for arm, spec in cfg["arms"].items():
        missing = [k for k in ("what", "model", "anchored") if k not in spec]
        if missing:
            raise SystemExit(f"{path}: arm {arm}: field(s) {', '.join(missing)} required")
        if spec.get("pretrain") and "train_set" not in spec["pretrain"]:
            raise SystemExit(f"{path}: arm {arm}: pretrain needs its train_set (epochs at least)")
    from zoo.protocol.benchmark import get_benchmark

    for name, own in (cfg.get("per_benchmark") or {}).items():
        where = f"{path}: per_benchmark.{name}"
        if not isinstance(own, dict) or set(own) - {"train_set", "pretrain"}:
            raise SystemExit(
                f"{where}: expected a mapping of train_set and pretrain (each of train_set "
                f"entries), got {own!r}"
            )
        for key, entries in own.items():
            if not isinstance(entries, dict) or {"train_set", "set"} & set(entries):
                raise SystemExit(
                    f"{where}.{key}: expected train_set entries (epochs: 6, ...), got {entries!r}"
                )
        if name == cfg["benchmark"]:
            raise SystemExit(f"{where}: the config's own benchmark; set its arms' recipes instead")
        if get_benchmark(name).representation != "mesh":
            raise SystemExit(f"{where}: not a mesh benchmark")
    for name in [None, *(cfg.get("per_benchmark") or {})]:
        moved = on_benchmark(cfg, name) if name else cfg
        for arm, spec in moved["arms"].items():
            stage = spec.get("pretrain")
            alone = (stage or {}).get("set", {}).get("autoencoder_epochs")
            if alone is not None and int(stage["train_set"]["epochs"]) > int(alone):
                raise SystemExit(
                    f"{path}: arm {arm}'s pretrain{' on ' + name if name else ''}: "
                    f"{stage['train_set']['epochs']} epochs but autoencoder_epochs {alone}: its "
                    f"later epochs would train the transformer too"
                )
    return cfg


def on_benchmark(cfg: dict, name: str) -> dict:
    """The config moved to mesh benchmark ``name``: its runs under ``<out>/<name>/``, and
    the settings ``per_benchmark`` gives ``name`` (if any) over every arm's own."""
    own = (cfg.get("per_benchmark") or {}).get(name) or {}
    arms = {}
    for arm, spec in cfg["arms"].items():
        spec = {
            **spec,
            "train_set": {**(spec.get("train_set") or {}), **own.get("train_set", {})},
        }
        if spec.get("pretrain"):
            stage = spec["pretrain"]
            spec["pretrain"] = {
                **stage,
                "train_set": {**stage["train_set"], **own.get("pretrain", {})},
            }
        arms[arm] = spec
    return {**cfg, "benchmark": name, "out": f"{cfg['out']}/{name}", "arms": arms}


def run_folder(cfg: dict, arm: str, seed: int) -> Path:
    return ROOT / cfg["out"] / f"{arm}-seed{seed}"


def train(cfg: dict, arm: str, seed: int) -> None:
    """Train (or resume) one arm and seed: its ``pretrain`` stage first where it has one (a
    run of its own, resumed the same way), then the arm's recipe from the stage's last
    weights."""
    if arm not in cfg["arms"]:
        raise SystemExit(f"arm {arm!r} unknown; arms: {', '.join(cfg['arms'])}")
    spec, out = cfg["arms"][arm], run_folder(cfg, arm, seed)
    init_from = None
    if spec.get("pretrain"):
        stage = spec["pretrain"]
        first = out.with_name(out.name + "-pretrain")
        _run(cfg, spec["model"], first, seed, {**cfg["train_set"], **stage["train_set"]},
             {**(spec.get("set") or {}), **(stage.get("set") or {})}, None)  # fmt: skip
        init_from = first / "last.pt"
    recipe = {**cfg["train_set"], **(spec.get("train_set") or {})}
    _run(cfg, spec["model"], out, seed, recipe, spec.get("set") or {}, init_from)


def _run(cfg, model, out: Path, seed: int, recipe: dict, hparams: dict, init_from) -> None:
    """One ``zoo train`` run into ``out``: resumed where it has a ``last.pt``, else started
    (from ``init_from`` where given); nothing to do when it has run its epochs."""
    if (out / "last.pt").is_file():
        from zoo.hub.checkpoints import read_checkpoint

        state = read_checkpoint(out / "last.pt")
        if state["epoch"] + 1 >= int(recipe["epochs"]):
            print(f"{out}: done ({state['epoch'] + 1} epochs)", flush=True)
            return
    command = [sys.executable, "-m", "zoo.cli", "train", "--model", model]
    command += ["--benchmark", cfg["benchmark"], "--out", str(out), "--seed", str(seed)]
    command += ["--no-progress"]
    if cfg["max_batches"]:
        command += ["--max-batches", str(cfg["max_batches"])]
    for key, value in recipe.items():
        text = json.dumps(value) if isinstance(value, (dict, list)) else value
        command += ["--train-set", f"{key}={text}"]
    for key, value in hparams.items():
        text = json.dumps(value) if isinstance(value, (dict, list)) else value
        command += ["--set", f"{key}={text}"]
    if (out / "last.pt").is_file():
        command.append("--resume")
    elif init_from is not None:
        command += ["--init-from", str(init_from)]
    print(" ".join(command), flush=True)
    subprocess.run(command, check=True, cwd=ROOT)


def _test_rmse(model, bench, protocol, name: str) -> dict:
    """RMSE at :data:`TEST_HORIZONS_MS` on the test windows (frame averaging, mean over
    actions), and MELV at 1000 ms as a multiple of the ground truth's: the model's
    (``melv``) and its autoencoder floor's (``floor``, a SpecTrHuMS model's)."""

    from zoo.evaluation.evaluator import Scored, evaluate_models

    (result,) = evaluate_models([Scored(model, name)], protocol, keep_going=False)
    frame = result.frame
    frame = frame[(frame.averaging == "frame") & (frame.action == "average")]
    rmse = frame[(frame.metric == "rmse") & (frame.model == name)].set_index("horizon_ms").value
    out = {ms: float(rmse[ms]) for ms in TEST_HORIZONS_MS if ms in rmse.index}
    melv = frame[(frame.metric == "melv") & (frame.horizon_ms == 1000)].set_index("model").value
    if "ground_truth" in melv.index:
        for key, who in (("melv", name), ("floor", name + ":autoencoder")):
            if who in melv.index:
                out[key] = float(melv[who] / melv["ground_truth"])
    return out


def score(cfg: dict) -> str:
    import torch

    from zoo.hub.checkpoints import read_checkpoint
    from zoo.hub.model_source import ModelSource
    from zoo.models.registry import load_registry
    from zoo.models.repeat_last import RepeatLast
    from zoo.protocol.benchmark import get_benchmark
    from zoo.protocol.plan import plan_protocol
    from zoo.train.split import split_train_val, usable_windows
    from zoo.train.validation import validate

    torch.set_grad_enabled(False)
    bench = get_benchmark(cfg["benchmark"])
    registry = load_registry()
    test = bench.load()
    training = bench.load(None, split=bench.train_split)
    protocol = plan_protocol(bench, test)
    t_in, t_out = bench.input_frames, bench.output_frames
    rows, reference = [], None
    for arm, spec in cfg["arms"].items():
        for seed in cfg["seeds"]:
            best = run_folder(cfg, arm, seed) / "best.pt"
            if not best.is_file():
                print(f"arm {arm}, seed {seed}: not trained ({best} missing)", file=sys.stderr)
                continue
            ckpt = read_checkpoint(best)
            recipe = ckpt["recipe"]
            # the budget of the whole run (last.pt), not up to its best epoch, and its first stage
            summary = read_checkpoint(best.with_name("last.pt"))["training"]
            _, held_out = split_train_val(
                training, recipe["val_fraction"], t_in + t_out, rule=recipe["val_split"]
            )
            positions, index = usable_windows(held_out, t_in + t_out, "all", t_in, t_out)
            stages = [summary, *([ckpt["init_from"]["training"]] if ckpt.get("init_from") else [])]
            samples = sum(t["samples_seen"] for t in stages)
            first = stages[1]["samples_seen"] // recipe["batch_size"] if len(stages) > 1 else 0
            budget = (
                f"{summary['epochs_run']}/{summary['epochs_planned']} epochs, "
                f"{samples // recipe['batch_size']} steps, {samples} samples, "
                f"{sum(t['seconds'] for t in stages) / 60:.0f} min, "
                f"{summary.get('device_name', '?')}"
                + (f" (a first stage of {first} steps)" if first else "")
            )
            for inference, name in (("paper", spec["model"]), ("anchored", spec["anchored"])):
                source = ModelSource.of(model=name, checkpoint=best, label=f"{arm}-{inference}")
                model = source.load(registry, bench, test).model
                val = validate(
                    model, positions, index, t_in, t_out, slice(None), "cpu",
                    fps=training.fps, curve="rmse",
                )  # fmt: skip
                rows.append(
                    (arm, seed, spec["what"], inference, ckpt["training"]["best"]["epoch"],
                     val, _test_rmse(model, bench, protocol, source.label), budget)
                )  # fmt: skip
                if reference is None:
                    still = RepeatLast(t_in, t_out, test.topology.num_vertices)
                    reference = (
                        val["val_horizons"]["repeat_last"],
                        len(index),
                        len(held_out),
                        _test_rmse(still, bench, protocol, "repeat_last"),
                    )
    if not rows:
        return "no arm trained yet"
    horizons = rows[0][5]["val_horizons"]["horizons"]
    tested = [f"{ms} ms" for ms in TEST_HORIZONS_MS]
    header = (
        ["arm", "seed", "change", "inference", "best epoch"]
        + [f"val {h}" for h in horizons]
        + ["val mean (mm)"]
        + [f"test {h}" for h in tested]
        + ["test MELV 1000 ms / truth's", "autoencoder floor's"]
        + ["budget"]
    )
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for arm, seed, what, inference, epoch, val, test_rmse, budget in rows:
        cells = [arm, str(seed), what, inference, str(epoch)]
        cells += [f"{v:.4f}" for v in val["val_horizons"]["model"]]
        cells += [f"{val['val_mpjpe']:.2f}"]
        cells += [f"{test_rmse.get(ms, float('nan')):.4f}" for ms in TEST_HORIZONS_MS]
        cells += [f"{test_rmse.get(k, float('nan')):.2f}" for k in ("melv", "floor")]
        lines.append("| " + " | ".join(cells + [budget]) + " |")
    val_reference, windows, recordings, test_reference = reference
    cells = ["–", "–", "repeat-last", "–", "–"] + [f"{v:.4f}" for v in val_reference] + ["–"]
    cells += [f"{test_reference.get(ms, float('nan')):.4f}" for ms in TEST_HORIZONS_MS]
    cells += ["–", "–"]
    lines.append("| " + " | ".join(cells + ["–"]) + " |")
    lines += [
        "",
        f"Validation: {windows} windows (sampler all) of {recordings} held-out recordings of "
        f"{cfg['benchmark']}'s training split; test: {bench.name}'s "
        f"{protocol.sampler} windows, raw ground truth. Normalised vertex RMSE.",
    ]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=HERE / "spectrhums_29.yaml")
    parser.add_argument(
        "--benchmark",
        help="another mesh benchmark than the config's (the winner's recipe where it ships); "
        "its runs go under <out>/<benchmark>/",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("train", help="train (or resume) one arm")
    run.add_argument("arm")
    run.add_argument("--seed", type=int, default=None, help="default: every seed of the config")
    sub.add_parser("score", help="score every trained arm; markdown on stdout")
    args = parser.parse_args(argv)
    cfg = load_config(args.config)
    if args.benchmark and args.benchmark != cfg["benchmark"]:
        from zoo.protocol.benchmark import get_benchmark

        if get_benchmark(args.benchmark).representation != "mesh":
            raise SystemExit(f"--benchmark {args.benchmark}: not a mesh benchmark")
        cfg = on_benchmark(cfg, args.benchmark)
    if args.command == "train":
        for seed in [args.seed] if args.seed is not None else cfg["seeds"]:
            train(cfg, args.arm, seed)
        return 0
    print(score(cfg))
    return 0


if __name__ == "__main__":
    sys.exit(main())
