"""The ``zoo`` command: list models, evaluate, regenerate leaderboards, train, build data."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from zoo.errors import ZooError
from zoo.options import CHECK_WINDOWS, EVAL_BATCH
from zoo.paths import REPO_ROOT
from zoo.registry import load_registry
from zoo.store import RESULTS_DIR


class UsageError(ZooError, ValueError):
    """A command-line argument is wrong; the message names it and what was expected."""


def parse_overrides(items: Sequence[str] | None) -> dict[str, Any]:
    """``--set key=value`` pairs, values parsed as YAML scalars (``3``, ``0.5``, ``[1, 2]``)."""
    out = {}
    for item in items or ():
        if "=" not in item:
            raise UsageError(f"--set expects key=value, got {item!r}")
        key, value = item.split("=", 1)
        out[key.strip()] = _numbers_as_numbers(yaml.safe_load(value))
    return out


def _numbers_as_numbers(value: Any) -> Any:
    """YAML 1.1 reads ``1e-3`` (no dot) as a string; a number is meant, in a value or nested."""
    if isinstance(value, str):
        try:
            return (
                float(value)
                if value.strip().lower() not in ("nan", "inf", "-inf", "infinity")
                else value
            )
        except ValueError:
            return value
    if isinstance(value, dict):
        return {k: _numbers_as_numbers(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_numbers_as_numbers(v) for v in value]
    return value


def _registry(args):
    return load_registry(*(args.registry or ()))


def cmd_list(args) -> int:
    """Each model as a short block (as ``pip show`` does): name, representation, whether it
    trains, its description and its full reference, wrapped to the terminal."""
    import shutil
    import textwrap

    registry = _registry(args)
    width = min(100, shutil.get_terminal_size((100, 24)).columns)
    blocks = []
    for name in registry.list_models(args.representation):
        e = registry.get(name)
        trains = (
            "trainable"
            if e.trainable
            else (f"runs {e.weights_of}'s weights" if e.weights_of else "not trained")
        )
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


def _source(args):
    from zoo.model_source import ModelSource

    return ModelSource.of(
        model=args.model,
        checkpoint=getattr(args, "checkpoint", None),
        weights=getattr(args, "weights", None),
        overrides=parse_overrides(args.set),
        label=getattr(args, "label", None),
    )


def _benchmark_of(args, source, default: str):
    """The benchmark asked for, else the one a trained model was trained for, else
    ``default``."""
    from zoo.benchmark import get_benchmark

    return get_benchmark(args.benchmark or source.benchmark() or default)


def cmd_eval(args) -> int:
    from zoo.distributed import init_distributed
    from zoo.pipeline import Subject, compute, place, store
    from zoo.protocol import plan_protocol
    from zoo.store import result_path, table_folder
    from zoo.tolerance import tolerance_text

    registry = _registry(args)
    source = _source(args)
    bench = _benchmark_of(args, source, "cmu")
    dataset = bench.load(args.data_root)
    loaded = source.load(registry, bench, dataset, args.data_root)
    loaded.warn_if_untrained()
    subject = Subject.of_loaded(loaded)
    samplers = args.sampler or [bench.sampler]
    if args.out and len(samplers) > 1:
        raise UsageError(
            "--out takes one --sampler; omit --out to write "
            "results/<benchmark>/<sampler>/<label>/ for each"
        )
    if args.melv_frames is not None and bench.representation != "mesh":
        raise UsageError(f"--melv-frames: benchmark {bench.name} is not a mesh benchmark")
    # Only a MELV other than the benchmark's default gets a folder of its own.
    melv = (
        args.melv_frames
        if args.melv_frames not in (None, getattr(bench, "melv_on", None))
        else None
    )
    plans = []
    for sampler in samplers:  # every output place checked before any evaluation
        folder = table_folder(sampler, args.task, args.ground_truth, args.horizon_frames, melv)
        out = (
            Path(args.out)
            if args.out
            else result_path(args.results, bench.name, folder, loaded.label)
        )
        protocol = plan_protocol(
            bench,
            dataset,
            sampler=sampler,
            task=args.task,
            horizon=args.horizon_frames,
            ground_truth=args.ground_truth,
            melv_frames=args.melv_frames,
        )
        plans.append((protocol, place(subject, protocol, out, replace=args.replace)))
    # Under torchrun every process scores its share of the windows and all get the whole
    # result; the first writes it.
    writer = init_distributed(args.device).rank == 0
    for protocol, where in plans:
        result = compute(
            subject,
            protocol,
            where.identity,
            made_by="zoo eval",
            device=args.device,
            batch_size=args.batch_size,
        )
        if not writer:
            continue
        stored = store(result, where)
        if stored.action == "kept":
            _print_average(result.frame, bench.horizons_ms)
            print(
                f"{where.folder}: agrees with the stored result of this identity (largest "
                f"difference {stored.agreed.share:.2f} of the tolerance, {tolerance_text()}); "
                f"left as stored"
            )
            continue
        if stored.action == "rewritten":
            print(
                f"{where.folder}: rewritten: the stored result of this identity {stored.agreed.why}"
            )
        _print_average(result.frame, bench.horizons_ms)
        print(f"wrote {where.folder}/results.csv, protocol.json, tables.md, windows.npz")
    return 0


def cmd_weights(args) -> int:
    from tabulate import tabulate

    from zoo.checkpoints import export_weights
    from zoo.weights import available_weights, read_weights_record, weights_file

    root = Path(args.root)
    if args.action == "export":
        if not args.checkpoint:
            raise UsageError(
                "zoo weights export needs a CHECKPOINT (e.g. checkpoints/cmu/spgsn/best.pt)"
            )
        path = export_weights(args.checkpoint, label=args.label, root=root, dtype=args.dtype)
        print(f"wrote {path} and {path.with_suffix('.json').name}")
        return 0
    if args.checkpoint or args.label:
        raise UsageError("zoo weights list takes no CHECKPOINT or --label")
    rows = []
    for bench, label in available_weights(root):
        record = read_weights_record(weights_file(bench, label, root))
        training = record.get("training", {})
        rows.append(
            [
                bench,
                label,
                record["model"],
                f"{record['parameters'] / 1e6:.2f} M",
                record["dtype"],
                training.get("samples_seen"),
                f"{training.get('seconds', 0) / 60:.0f}",
                training.get("device_name"),
            ]
        )
    print(
        tabulate(
            rows,
            headers=[
                "benchmark",
                "label",
                "model",
                "parameters",
                "stored as",
                "training samples",
                "minutes",
                "device",
            ],
            tablefmt="github",
        )
    )
    return 0


def cmd_leaderboard(args) -> int:
    import time

    from zoo.check import CheckReport, fresh_seed
    from zoo.leaderboard import Plan, regenerate

    registry = _registry(args)
    if args.windows is not None and args.windows < 1:
        raise UsageError(f"--windows {args.windows}: expected a positive number of windows")
    if args.seed is not None and not 0 <= args.seed < 2**32:
        raise UsageError(f"--seed {args.seed}: expected an integer in 0..2**32-1")
    if args.windows is not None and args.full:
        raise UsageError("--windows samples; --full checks every window: give one of them")
    windows = None if args.full else (args.windows or CHECK_WINDOWS)
    seed = args.seed if args.seed is not None else fresh_seed()
    check = CheckReport(windows=windows, seed=seed) if args.check else None
    if check and (args.recompute is not None or args.model or args.drop):
        raise UsageError(
            "--check recomputes every committed row and writes nothing; it takes "
            "no --recompute, --model or --drop"
        )
    if check:
        print(
            "zoo leaderboard --check: "
            + (
                "every window of every table (--full)"
                if windows is None
                else f"{windows} windows a table, every action among them (seed {seed}; "
                f"--seed {seed} draws them again; --full checks every window)"
            ),
            file=sys.stderr,
        )
    if not args.benchmark:
        args.benchmark = (
            committed_benchmarks(Path(args.out)) if check else list(default_benchmarks())
        )
    names = [Path(b).stem for b in args.benchmark]
    unknown = sorted(set(args.recompute or ()) - set(names))
    if unknown:
        raise UsageError(
            f"--recompute {' '.join(unknown)}: not among the benchmarks of this run "
            f"({', '.join(names)})"
        )
    if check:
        from zoo.results import TABLE_FILE, table_files

        for name in names:
            if not table_files(Path(args.out) / name):
                raise UsageError(
                    f"--check: no committed table of {name} under {args.out} "
                    f"(expected {args.out}/{name}/<sampler>/{TABLE_FILE})"
                )
    started = time.perf_counter()
    for bench, name in zip(args.benchmark, names):
        plan = Plan(
            recompute=args.recompute is not None and (not args.recompute or name in args.recompute),
            models=frozenset(args.model or ()),
            drop=frozenset(args.drop or ()),
            check=check,
            windows=windows,
            seed=seed,
        )
        run = lambda bench=bench, plan=plan: regenerate(  # noqa: E731
            bench,
            registry=registry,
            data_root=args.data_root,
            out_root=Path(args.out),
            checkpoints=Path(args.checkpoints),
            weights=Path(args.weights),
            device=args.device,
            plan=plan,
        )
        if check is None:
            run()
            continue
        print(f"checking {name} ...", file=sys.stderr)
        try:  # a benchmark that cannot be loaded at all is reported; the others are checked
            run()
        except Exception as e:  # noqa: BLE001
            check.start_table(f"{name} (not loaded, or a table not finished)")
            check.problem(f"{name}: not checked: {e}")
    if check is None:
        from zoo.report import write_index

        print(f"wrote {write_index(Path(args.out))} ({time.perf_counter() - started:.0f} s)")
        return 0
    for problem in check.problems:
        print(f"zoo leaderboard --check: {problem}", file=sys.stderr)
    first, *rest = check.summary()
    print(
        f"{first} ({', '.join(names)}; {time.perf_counter() - started:.0f} "
        f"s){'' if not check.problems else f'; {len(check.problems)} problem(s) above'}"
    )
    for line in rest:
        print(line)
    return 1 if check.problems else 0


def cmd_costs(args) -> int:
    import time

    from zoo.costs import measure_costs
    from zoo.report import write_index

    if not args.seconds > 0:
        raise UsageError(f"--seconds {args.seconds:g}: expected a positive time budget")
    registry = _registry(args)
    benchmarks = args.benchmark or committed_benchmarks(Path(args.out))
    if not benchmarks:
        raise UsageError(f"{args.out}: no committed table; give --benchmark NAME")
    started = time.perf_counter()
    for bench in benchmarks:
        measure_costs(
            bench,
            registry=registry,
            data_root=args.data_root,
            out_root=Path(args.out),
            weights=Path(args.weights),
            checkpoints=Path(args.checkpoints),
            device=args.device,
            models=args.model or (),
            seconds=args.seconds,
        )
    print(f"wrote {write_index(Path(args.out))} ({time.perf_counter() - started:.0f} s)")
    return 0


def cmd_cards(args) -> int:
    from zoo.cards import build_cards

    statuses = build_cards(
        Path(args.out),
        registry=_registry(args),
        weights_root=Path(args.weights),
        results_root=Path(args.results),
        write=not args.check,
    )
    stale = [s for s in statuses if not s.fresh]
    for s in statuses:
        state = "up to date" if s.fresh else s.reason
        verb = "" if s.fresh or args.check else " (rewritten)"
        print(f"{s.path}: {state}{verb}")
        if args.check:
            for line in s.diff[:6]:
                print(f"    {line}")
    if args.check and stale:
        print(f"{len(stale)} of {len(statuses)} card(s) stale: run `zoo cards` to rewrite them")
        return 1
    return 0


def cmd_site(args) -> int:
    from zoo.site import build_site

    results = Path(args.results)
    if args.clips:
        from zoo.clips import CLIPS_FILE, write_benchmark_clips

        registry = _registry(args)
        for name in args.benchmark or _mesh_benchmarks(results):
            path = write_benchmark_clips(
                name, registry, Path(args.weights), results / name / CLIPS_FILE, args.data_root
            )
            print(f"wrote {path}")
    build = build_site(
        Path(args.out),
        results,
        weights_root=Path(args.weights),
        cards_dir=Path(args.cards),
        registry=_registry(args),
    )
    for line in build.warnings:
        print(f"warning: {line}", file=sys.stderr)
    print(
        f"wrote {len(build.pages)} pages to {build.out} ({build.bytes / 1e6:.1f} MB) in "
        f"{build.seconds:.1f} s: open {build.out / 'index.html'} in a browser (file://, offline)"
    )
    return 0


def _mesh_benchmarks(results: Path) -> list[str]:
    from zoo.benchmark import get_benchmark

    return [
        name
        for name in committed_benchmarks(results)
        if get_benchmark(name).representation == "mesh"
    ]


def committed_benchmarks(results: Path) -> list[str]:
    """Every benchmark with a table under ``results`` (what ``--check`` checks by default)."""
    from zoo.benchmark import list_benchmarks
    from zoo.results import table_files

    known = set(list_benchmarks())
    found = sorted(p.parent.parent.name for p in table_files(results, depth=2))
    unknown = sorted({b for b in found if b not in known})
    if unknown:
        raise UsageError(
            f"{results}: tables of unknown benchmark(s) {', '.join(unknown)} "
            f"(known: {', '.join(sorted(known))})"
        )
    return list(dict.fromkeys(found))


def cmd_compare(args) -> int:
    from zoo.comparison import compare

    folders = []
    for name in (args.a, args.b):
        if Path(name).is_dir():
            folders.append(Path(name))
            continue
        if not args.benchmark:
            raise UsageError(
                f"{name!r} is not a result folder; give --benchmark to find "
                f"results/<benchmark>/<sampler>/{name}"
            )
        from zoo.benchmark import get_benchmark
        from zoo.store import result_path, table_folder

        bench = get_benchmark(args.benchmark)
        folder = result_path(
            args.results,
            bench.name,
            table_folder(args.sampler or bench.sampler, truth=args.ground_truth),
            name,
        )
        if not (folder / "results.csv").is_file():
            raise UsageError(
                f"{folder}: no result of {name!r} there (zoo eval or zoo leaderboard writes it)"
            )
        folders.append(folder)
    comparison = compare(
        folders[0],
        folders[1],
        metric=args.metric,
        joints=args.joints,
        averaging=args.averaging,
        block_frames=args.block_frames,
        confidence=args.confidence,
        replicates=args.replicates,
        seed=args.seed,
    )
    print(comparison.markdown())
    if args.out:
        comparison.write(args.out)
        print(f"wrote {args.out}/comparison.md, comparison.png")
    return 0


def cmd_render(args) -> int:
    from zoo.render import render_windows

    registry = _registry(args)
    source = _source(args)
    bench = _benchmark_of(args, source, "cloth")
    if bench.representation != "mesh":
        raise UsageError(f"zoo render draws meshes; benchmark {bench.name!r} is a skeleton one")
    dataset = bench.load(args.data_root)
    loaded = source.load(registry, bench, dataset, args.data_root)
    out = Path(args.out) if args.out else RESULTS_DIR / bench.name / "renders"
    written = render_windows(
        loaded.model,
        loaded.label,
        bench,
        dataset,
        args.windows,
        out,
        task=args.task,
        horizon=args.horizon_frames,
    )
    print("wrote " + ", ".join(str(p) for p in written))
    return 0


def default_benchmarks():
    """The main job: the embedded cloth benchmark (generated here, no download), plus CMU when
    its motion-capture files are present."""
    from zoo.benchmark import get_benchmark

    yield "cloth"
    cmu = get_benchmark("cmu")
    if cmu.resolve_data_root() is not None and cmu.resolve_data_root().is_dir():
        yield "cmu"
    else:
        print(
            f"note: CMU Mocap not found at {cmu.resolve_data_root()}; evaluating the cloth "
            f"benchmark only (zoo leaderboard --benchmark cmu --data-root PATH for CMU)",
            file=sys.stderr,
        )


def cmd_train(args) -> int:
    from zoo.train.loop import train

    if args.out:  # a file there, or an unwritable place, is refused before training
        from zoo.io import check_writable

        check_writable(args.out, what=f"--out {args.out}")
    registry = _registry(args)
    best = train(
        args.model,
        args.benchmark,
        registry=registry,
        epochs=args.epochs,
        out_dir=args.out,
        data_root=args.data_root,
        overrides=parse_overrides(args.set),
        train_overrides=parse_overrides(args.train_set),
        resume=args.resume,
        seed=args.seed,
        device=args.device,
        max_batches=args.max_batches,
        progress=not args.no_progress,
        init_from=args.init_from,
        cuda_graph=args.cuda_graph,
    )
    print(
        f"wrote {best} (best validation epoch) and {best.parent / 'last.pt'} (last epoch): "
        f"zoo eval --checkpoint {best} scores it, zoo leaderboard picks up "
        f"checkpoints/<benchmark>/<model>/, zoo weights export {best} ships it"
    )
    return 0


def _data_basis(bench, args) -> int:
    """``zoo data basis NAME``: the basis this machine computes for the benchmark's mesh,
    aligned to the shipped reference and checked against it; ``--ship`` writes the reference
    for a mesh that has none yet."""
    import time

    from zoo.data.spectral import BasisReference, SpectralBasis, reference_path

    if bench.spectral_k is None:
        raise UsageError(f"benchmark {bench.name} has no spectral basis (no spectral_k)")
    topology = bench.load_mesh(args.data_root).topology
    path = reference_path(topology, bench.spectral_k)
    if args.ship and path.is_file():
        raise UsageError(
            f"{path} is shipped already (trained weights depend on its frame); delete it "
            f"deliberately to ship another"
        )
    if not args.ship and not path.is_file():
        raise UsageError(
            f"no shipped basis reference for {bench.name} ({path}); zoo data basis "
            f"{bench.name} --ship writes one"
        )
    print(f"computing the basis of {topology.name} (k={bench.spectral_k}) ...", file=sys.stderr)
    started = time.perf_counter()
    computed = SpectralBasis.compute(topology, bench.spectral_k)
    took = time.perf_counter() - started
    if args.ship:
        BasisReference.of(computed).save(path)
        print(f"wrote {path} ({computed.solver}, {took:.1f} s)")
        return 0
    reference = BasisReference.load(path)
    report = reference.misfit(computed)
    print(
        f"{bench.name}: basis {reference.hash[:12]} computed here in {took:.1f} s: eigenvalues "
        f"within {report['eigenvalues']:.2g} of the shipped reference, probe projections "
        f"within {report['misfit']:.2g} after alignment (worst: vectors "
        f"{report['worst_group']}): {'the same basis' if report['same'] else 'ANOTHER BASIS'}"
    )
    return 0 if report["same"] else 1


def _data_regressor(bench, args) -> int:
    """``zoo data regressor NAME``: fit the benchmark body's joint regressor here and compare it
    with the shipped one; ``--ship`` writes it for a recipe that has none yet."""
    import time

    from zoo.benchmark import MESH_DATASETS
    from zoo.data import anny_motion as am

    loader, options = MESH_DATASETS.get(bench.dataset, (None, {}))
    if not str(loader).endswith(":cmu_anny_dataset"):
        raise UsageError(
            f"benchmark {bench.name} has no fitted joint regressor (only the CMU-on-Anny "
            f"benchmarks fit one)"
        )
    topology = options["topology"]
    root = args.data_root or bench.resolve_data_root()
    if root is None:
        raise UsageError(f"{bench.name}: give --data-root (the CMU BVH folder)")
    path = am.shipped_regressor_path(topology, am.regressor_recipe(root, topology)[0])
    if args.ship:
        if path.is_file():
            raise UsageError(
                f"{path} is shipped already (committed MPJPE rows depend on it); delete it "
                f"deliberately to ship another"
            )
        import shutil
        import tempfile

        # The one fitting path (joint_regressor, which fits where none is shipped), into a
        # scratch cache, then its file moved to where it ships.
        with tempfile.TemporaryDirectory() as scratch:
            fitted = am.joint_regressor(root, topology, cache_dir=scratch)
            path.parent.mkdir(parents=True, exist_ok=True)
            shutil.move(fitted.source, path)
        print(f"wrote {path} ({fitted.matrix.nnz} weights; fit {fitted.recipe['fit_mean_mm']} mm)")
        return 0
    print(f"fitting the joint regressor of the {topology} Anny body ...", file=sys.stderr)
    started = time.perf_counter()
    report = am.check_joint_regressor(root, topology)
    took = time.perf_counter() - started
    print(
        f"{bench.name}: joint regressor {report['path'].name} fitted here in {took:.1f} s: "
        f"weights within {report['weights']:.2g} of the shipped ones ({report['support'][0]} "
        f"against {report['support'][1]} non-zeros; a joint's row within "
        f"{report['rows_l1']:.2g} in L1), regressed joints on the fit's "
        f"{int(report['stats']['fit_frames'][0])} frames within {report['joints_mm']:.3g} mm "
        f"(mean {report['joints_mean_mm']:.2g} mm; tolerance {am.REGRESSOR_TOLERANCE_MM} mm): "
        + (
            "the same regressor"
            if report["same"]
            else "another regressor (the full-body fit is ill-conditioned: another CPU's "
            "skinning moves its weights; docs/reproducibility.md)"
        )
    )
    here, recorded = report["shipped_here"], report["stats"]
    print(
        f"the shipped regressor on the fit's frames skinned here: misses the bone heads by "
        f"{here['fit_mean_mm']:.3f} mm on average, {here['fit_p99_mm']:.3f} at the 99th "
        f"percentile (its record: {recorded['fit_mean_mm'][1]}, {recorded['fit_p99_mm'][1]}): "
        + ("as recorded" if report["fits_here"] else "NOT AS RECORDED")
    )
    return 0 if report["fits_here"] else 1


def cmd_data(args) -> int:
    from tabulate import tabulate

    from zoo.benchmark import get_benchmark, list_benchmarks
    from zoo.data.catalog import describe, export_window

    if args.action == "list":
        rows = []
        for name in list_benchmarks():
            b = get_benchmark(name)
            rows.append(
                [
                    name,
                    b.dataset,
                    b.representation,
                    b.split,
                    b.train_split,
                    str(
                        b.resolve_data_root()
                        or ("(generated)" if b.representation == "mesh" else "(give --data-root)")
                    ),
                ]
            )
        print(
            tabulate(
                rows,
                headers=[
                    "benchmark",
                    "dataset",
                    "representation",
                    "test split",
                    "train split",
                    "data root",
                ],
                tablefmt="github",
            )
        )
        for line in _skipped_data(args.data_root):
            print(f"note: {line}")
        return 0
    if not args.benchmark:
        raise UsageError(f"zoo data {args.action} needs a benchmark name (see zoo data list)")
    bench = get_benchmark(args.benchmark)
    if args.split not in (None, "all", bench.split, bench.train_split):
        raise UsageError(
            f"--split {args.split!r}: benchmark {bench.name} has splits "
            f"{bench.split} (test) and {bench.train_split} (train), or 'all'"
        )
    splits = (
        [bench.split, bench.train_split] if args.split == "all" else [args.split or bench.split]
    )
    if args.action == "basis":
        return _data_basis(bench, args)
    if args.action == "regressor":
        return _data_regressor(bench, args)
    if args.action in ("build", "describe"):
        for split in splits:
            dataset = bench.load(args.data_root, split=split)
            info = describe(dataset)
            print(tabulate(list(info.items()), tablefmt="plain"))
            print()
        return 0
    if args.action == "export":
        if not args.out:
            raise UsageError("zoo data export needs --out FILE.ply or FILE.glb")
        dataset = bench.load(args.data_root, split=splits[0])
        written = export_window(dataset, bench, args.window, args.out, sampler=args.sampler)
        print(
            f"wrote {', '.join(str(p) for p in written[:3])}"
            f"{f' and {len(written) - 3} more' if len(written) > 3 else ''}"
        )
        return 0
    raise UsageError(f"unknown data action {args.action!r}")


def _print_average(frame, horizons) -> None:
    from tabulate import tabulate

    from zoo.tables import default_horizons

    # a long-term run's horizons past the benchmark's last
    horizons = [*horizons, *(h for h in default_horizons(frame) if h > max(horizons))]
    avg = frame[(frame["action"] == "average") & frame["horizon_ms"].isin(horizons)]
    keys = ["model", "metric", "averaging", "joints"]
    table = avg.pivot_table(index=keys, columns="horizon_ms", values="value")
    print(
        tabulate(
            table.reset_index(),
            headers=keys + [f"{h} ms" for h in table.columns],
            tablefmt="github",
            floatfmt=".4g",
            showindex=False,
        )
    )


def _skipped_data(data_root) -> list[str]:
    """Files and folders in the CMU data roots that the loader passes over (each once)."""
    from zoo.benchmark import get_benchmark, list_benchmarks
    from zoo.data.motion import CMU_ACTIONS, cmu_skipped

    lines = []
    for name in list_benchmarks():
        bench = get_benchmark(name)
        root = bench.resolve_data_root(data_root) if bench.dataset == "cmu_mocap" else None
        if root is None or not root.is_dir():
            continue
        for split in dict.fromkeys((bench.split, bench.train_split)):
            for line in cmu_skipped(root, split, bench.actions or CMU_ACTIONS):
                entry = f"{root}/{line}"
                if entry not in lines:
                    lines.append(entry)
    return lines


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def task_options(p) -> None:
    """``--task`` (one of the evaluator's tasks, ``zoo.options.TASKS``) and its horizon."""
    from zoo.options import TASKS

    p.add_argument(
        "--task",
        default="prediction",
        choices=list(TASKS),
        help="what the model is asked: the next frames, the frames between, or a long rollout",
    )
    p.add_argument("--horizon-frames", type=int, help="frames to predict for --task longterm")


def build_parser() -> argparse.ArgumentParser:
    from zoo.version import __version__

    parser = argparse.ArgumentParser(prog="zoo", description=__doc__)
    parser.add_argument("--version", action="version", version=f"motion-zoo {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    def common(p, model_required=False):
        p.add_argument(
            "--registry",
            action="append",
            metavar="YAML",
            help="extra registry file (your own baselines); repeatable",
        )
        p.add_argument("--data-root", help="dataset folder (default: the benchmark's)")
        p.add_argument("--device", default="cpu", help="torch device (default cpu)")

    p = sub.add_parser("list", help="list registered models")
    p.add_argument("--registry", action="append", metavar="YAML", help="extra registry file")
    p.add_argument(
        "--representation", choices=["joints", "mesh"], help="only models of this representation"
    )
    p.set_defaults(func=cmd_list)

    p = sub.add_parser("eval", help="evaluate one model on one benchmark")
    common(p)
    p.add_argument("--model", help="registered model name")
    p.add_argument("--checkpoint", help="trained checkpoint (from zoo train)")
    p.add_argument("--weights", help="shipped weights (weights/<benchmark>/<label>.safetensors)")
    p.add_argument(
        "--benchmark", help="benchmark name or YAML path (default: the checkpoint's, else cmu)"
    )
    p.add_argument(
        "--sampler",
        action="append",
        help="window sampler (ltd8, rand256, all, strideK, strideK_strict); "
        "repeatable; default the benchmark's",
    )
    p.add_argument("--out", help="output folder (default results/<benchmark>/<sampler>/<label>)")
    p.add_argument("--results", default=str(RESULTS_DIR), help="results root (default results/)")
    p.add_argument(
        "--label",
        help="the row's label and folder name (default: the model's name, "
        "<model>@last for a last.pt, <model>+key=value with --set)",
    )
    p.add_argument(
        "--replace",
        action="store_true",
        help="replace a stored result of another identity (other hyper-parameters, "
        "data, weights or code) in the same place",
    )
    p.add_argument(
        "--set", action="append", metavar="KEY=VALUE", help="override a hyper-parameter; repeatable"
    )
    p.add_argument(
        "--batch-size",
        type=_positive_int,
        default=EVAL_BATCH,
        help=f"windows per forward pass (default {EVAL_BATCH})",
    )
    task_options(p)
    p.add_argument(
        "--ground-truth",
        choices=["raw", "spectral"],
        help="mesh benchmarks: score against raw or k-coefficient vertices",
    )
    p.add_argument(
        "--melv-frames",
        choices=["raw", "spectral"],
        help="mesh benchmarks: MELV on the frames as they are (raw) or on their "
        "k-coefficient reconstructions (spectral, the default where the "
        "benchmark has a basis; as SpecTrHuMS measures)",
    )
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("leaderboard", help="re-evaluate and rebuild results/<benchmark>/")
    common(p)
    p.add_argument(
        "--benchmark",
        action="append",
        help="benchmark(s); default cloth, and cmu where its data is present",
    )
    p.add_argument("--out", default=str(RESULTS_DIR), help="results root (default results/)")
    p.add_argument(
        "--weights",
        default=str(REPO_ROOT / "weights"),
        help="folder of shipped weights <benchmark>/<label>.safetensors (default "
        "weights/); a trained row with shipped weights is computed from them",
    )
    p.add_argument(
        "--checkpoints",
        default=str(REPO_ROOT / "checkpoints"),
        help="folder of trained checkpoints <benchmark>/<model>/best.pt "
        "(default checkpoints/, where zoo train writes)",
    )
    p.add_argument(
        "--check",
        action="store_true",
        help="write nothing: recompute every row of every committed table (default: "
        "every benchmark under --out) on a sample of its windows (--windows, --full), "
        "recompute each row's averages from its stored per-window errors, and exit 1 "
        "naming each value that differs by more than float32 rounding across CPUs "
        "(tolerances in the summary) and each row whose weights are not the recorded ones",
    )
    p.add_argument(
        "--windows",
        type=int,
        metavar="N",
        help=f"windows a table's sample has (default {CHECK_WINDOWS}, every action among "
        "them): what --check recomputes, and what verifies a row stale only because code "
        "changed before it is re-stamped",
    )
    p.add_argument(
        "--seed",
        type=int,
        help="the sample's seed (default: drawn anew each run, and printed)",
    )
    p.add_argument(
        "--full",
        action="store_true",
        help="every window: --check recomputes every row in full, and a row stale only "
        "because code changed is recomputed instead of verified on a sample",
    )
    p.add_argument(
        "--model",
        action="append",
        metavar="NAME",
        help="add or refresh only this model's rows (repeatable); every other "
        "stored row is kept as it is",
    )
    p.add_argument(
        "--recompute",
        nargs="*",
        metavar="BENCHMARK",
        help="recompute every row (of these benchmarks; alone: of all) instead of "
        "reusing stored rows whose identity holds",
    )
    p.add_argument(
        "--drop",
        action="append",
        metavar="LABEL",
        help="remove this row's result folder from the tables (repeatable): the way "
        "to delete a row the leaderboard did not make",
    )
    p.set_defaults(func=cmd_leaderboard)

    from zoo.options import COST_SECONDS

    p = sub.add_parser(
        "costs",
        help="measure the tables' cost columns (float32, time-boxed) into "
        "results/<benchmark>/costs.json and re-render those columns",
    )
    common(p)
    p.add_argument(
        "--benchmark",
        action="append",
        help="benchmark(s); default every benchmark with tables under --out",
    )
    p.add_argument(
        "--model",
        action="append",
        metavar="NAME",
        help="measure only this registry model's rows (repeatable); the other stored costs "
        "are kept",
    )
    p.add_argument(
        "--seconds",
        type=float,
        default=COST_SECONDS,
        help=f"time budget per model (default {COST_SECONDS:g}); a slow model gets fewer "
        f"latency calls and training steps, and says so",
    )
    p.add_argument("--out", default=str(RESULTS_DIR), help="results root (default results/)")
    p.add_argument(
        "--weights",
        default=str(REPO_ROOT / "weights"),
        help="folder of shipped weights (default weights/), as zoo leaderboard",
    )
    p.add_argument(
        "--checkpoints",
        default=str(REPO_ROOT / "checkpoints"),
        help="folder of trained checkpoints (default checkpoints/), as zoo leaderboard",
    )
    p.set_defaults(func=cmd_costs)

    p = sub.add_parser(
        "cards",
        help="write the model cards (docs/models/<model>.md) from the registry, the shipped "
        "weights' records and results/; --check names the stale ones",
    )
    p.add_argument(
        "--registry", action="append", default=[], metavar="YAML", help="extra registry file"
    )
    p.add_argument("--check", action="store_true", help="write nothing; exit 1 if a card is stale")
    p.add_argument("--out", default=str(REPO_ROOT / "docs" / "models"), help="cards folder")
    p.add_argument("--weights", default=str(REPO_ROOT / "weights"), help="shipped weights folder")
    p.add_argument("--results", default=str(RESULTS_DIR), help="results root")
    p.set_defaults(func=cmd_cards)

    p = sub.add_parser(
        "site",
        help="build the leaderboards as a static site (every table, curve, card and mesh clip; "
        "opens from file://, offline)",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--out", default=str(REPO_ROOT / "site"), help="site folder (replaced whole)")
    p.add_argument("--results", default=str(RESULTS_DIR), help="results root to read")
    p.add_argument("--weights", default=str(REPO_ROOT / "weights"), help="shipped weights folder")
    p.add_argument("--cards", default=str(REPO_ROOT / "docs" / "models"), help="model cards folder")
    p.add_argument(
        "--clips",
        action="store_true",
        help="first (re)write each mesh benchmark's clips.npz from its data and shipped weights "
        "(minutes; the site itself needs neither)",
    )
    p.add_argument(
        "--benchmark",
        action="append",
        default=[],
        help="with --clips: only this mesh benchmark (repeatable; default: every mesh benchmark "
        "with a table)",
    )
    p.add_argument("--data-root", help="with --clips: the benchmark's data folder")
    p.add_argument(
        "--registry", action="append", default=[], metavar="YAML", help="extra registry file"
    )
    p.set_defaults(func=cmd_site)

    p = sub.add_parser(
        "compare",
        help="is A better than B? paired differences per horizon, intervals, sign test",
    )
    p.add_argument("a", help="model label (with --benchmark) or result folder")
    p.add_argument("b", help="model label (with --benchmark) or result folder")
    p.add_argument("--benchmark", help="benchmark whose results/<benchmark>/<sampler>/ to read")
    p.add_argument("--sampler", help="window sampler (default: the benchmark's)")
    p.add_argument(
        "--ground-truth",
        choices=["raw", "spectral"],
        help="mesh benchmarks: the results scored against this ground truth",
    )
    p.add_argument("--results", default=str(RESULTS_DIR), help="results root (default results/)")
    p.add_argument("--metric", help="default: the benchmark's headline (mpjpe; rmse on meshes)")
    p.add_argument("--joints", help="joint protocol (default: the official one, e.g. all38)")
    p.add_argument(
        "--averaging",
        default="frame",
        choices=["frame", "cumulative"],
        help="error at each frame, or the mean up to it",
    )
    p.add_argument(
        "--block-frames",
        type=_positive_int,
        help="bootstrap block length in frames (default: eight window lengths)",
    )
    p.add_argument("--confidence", type=float, default=0.95, help="level of the intervals")
    p.add_argument("--replicates", type=_positive_int, default=2000, help="bootstrap replicates")
    p.add_argument("--seed", type=int, default=0, help="seed of the bootstrap")
    p.add_argument("--out", help="also write comparison.md and comparison.png here")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("render", help="ground truth and prediction side by side (PNG, .glb)")
    common(p)
    p.add_argument("--model", help="registered model name")
    p.add_argument("--checkpoint", help="trained checkpoint (from zoo train)")
    p.add_argument("--weights", help="shipped weights (weights/<benchmark>/<label>.safetensors)")
    p.add_argument(
        "--benchmark", help="mesh benchmark (default: the checkpoint's or weights', else cloth)"
    )
    p.add_argument(
        "--windows", type=int, nargs="+", default=[0, 1, 2], help="test windows to draw, by number"
    )
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="model hyper-parameter")
    task_options(p)
    p.add_argument("--out", help="folder (default results/<benchmark>/renders)")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("data", help="build, list, describe and export datasets")
    p.add_argument("action", choices=["list", "build", "describe", "export", "basis", "regressor"])
    p.add_argument("benchmark", nargs="?", help="benchmark whose dataset to use")
    p.add_argument("--split", help="split (default: the benchmark's test split; 'all': both)")
    p.add_argument("--data-root", help="dataset folder (default: the benchmark's)")
    p.add_argument("--window", type=int, default=0, help="export: window index (default 0)")
    p.add_argument("--sampler", help="export: window sampler (default: the benchmark's)")
    p.add_argument(
        "--ship",
        action="store_true",
        help="basis, regressor: compute and write benchmarks/bases/ (benchmarks/regressors/) "
        "for a mesh that has none shipped",
    )
    p.add_argument(
        "--out", help="export: FILE.glb (all frames side by side) or FILE.ply (one file per frame)"
    )
    p.set_defaults(func=cmd_data)

    p = sub.add_parser(
        "weights", help="export a checkpoint's weights for shipping, or list the shipped ones"
    )
    p.add_argument("action", choices=["export", "list"])
    p.add_argument("checkpoint", nargs="?", help="export: the checkpoint (best.pt or last.pt)")
    p.add_argument("--label", help="export: label (default <model>, or <model>@last for last.pt)")
    p.add_argument(
        "--dtype",
        default="float16",
        choices=["float16", "float32"],
        help="export: storage precision (default float16: half the size)",
    )
    p.add_argument(
        "--root", default=str(REPO_ROOT / "weights"), help="weights folder (default weights/)"
    )
    p.set_defaults(func=cmd_weights)

    p = sub.add_parser("train", help="train a model on a benchmark's training split")
    common(p)
    p.add_argument("--model", required=True, help="registered model name")
    p.add_argument("--benchmark", default="cmu", help="benchmark whose training split to learn")
    p.add_argument("--epochs", type=int, help="default: the registry recipe's")
    p.add_argument("--out", help="run folder (default checkpoints/<benchmark>/<model>)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="model hyper-parameter")
    p.add_argument(
        "--train-set",
        action="append",
        metavar="KEY=VALUE",
        help="training-recipe override (lr, batch_size, ...)",
    )
    p.add_argument("--resume", action="store_true", help="continue from the run's last state")
    p.add_argument(
        "--init-from",
        metavar="PATH",
        help="start from this checkpoint (best.pt or last.pt) or shipped weights "
        "(.safetensors) of the same model and benchmark, with a fresh optimiser "
        "and schedule: a new stage of training, recorded with the source's budget",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of weights, order and dropout")
    p.add_argument("--max-batches", type=int, help="cap batches per epoch (quick runs)")
    p.add_argument(
        "--no-progress",
        action="store_true",
        help="no progress bar even on a terminal (a log or pipe never gets one)",
    )
    p.add_argument(
        "--cuda-graph",
        action="store_true",
        help="on one CUDA device, capture each epoch's step once as a CUDA graph and replay it "
        "(small models train several times faster; a step that reads values back to decide "
        "what to do cannot be captured and is refused)",
    )
    p.set_defaults(func=cmd_train)
    return parser


def check_device(device: str) -> None:
    """An unknown device, or one this machine lacks, is a usage error before any work."""
    import torch

    try:
        kind = torch.device(device).type
    except (RuntimeError, ValueError):
        raise UsageError(
            f"--device {device!r}: not a torch device; e.g. cpu, cuda, cuda:1"
        ) from None
    if kind == "cuda" and not torch.cuda.is_available():
        raise UsageError(
            f"--device {device}: this machine has no CUDA device (torch "
            f"{torch.__version__}); use --device cpu"
        )
    if kind not in ("cpu", "cuda"):
        raise UsageError(f"--device {device}: the zoo runs on cpu or cuda, not {kind}")


def _shape_overrides(overrides: dict[str, Any], benchmark: str | None) -> None:
    from zoo.registry import SHAPE_ARGS

    fixed = sorted(set(overrides) & set(SHAPE_ARGS))
    if fixed:
        raise UsageError(
            f"--set {', '.join(fixed)}: fixed by the benchmark "
            f"({benchmark or 'cmu'}), not a hyper-parameter; use a benchmark YAML "
            f"file with other input_frames / output_frames to change them"
        )


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if getattr(args, "device", None) is not None:
            check_device(args.device)
        if getattr(args, "set", None):
            _shape_overrides(parse_overrides(args.set), getattr(args, "benchmark", None))
        return args.func(args)
    except ZooError as e:
        print(f"zoo {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(
            f"zoo {args.command}: interrupted (nothing half-written is left; a training run "
            f"continues with --resume)",
            file=sys.stderr,
        )
        return 130


if __name__ == "__main__":
    sys.exit(main())
