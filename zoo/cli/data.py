"""``zoo data list|build|describe|export|basis|regressor``: the benchmarks' datasets."""

from __future__ import annotations

import sys

from zoo.cli.common import UsageError, add_command


def add(sub) -> None:
    p = add_command(sub, "data", "build, list, describe and export datasets", None)
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    listing = add_command(actions, "list", "the benchmarks, their datasets and data roots", show)
    listing.add_argument("--data-root", help="dataset folder to look in for skipped files")
    for name, what in (
        ("build", "build (or load) a benchmark's dataset and describe it"),
        ("describe", "describe a benchmark's dataset: sequences, frames, points, source"),
    ):
        a = add_command(actions, name, what, describe_data)
        _dataset_arguments(a)
    e = add_command(
        actions, "export", "write one window of a benchmark's dataset as meshes", export
    )
    _dataset_arguments(e)
    e.add_argument("--window", type=int, default=0, help="window index")
    e.add_argument("--sampler", help="window sampler (default: the benchmark's)")
    e.add_argument(
        "--out",
        required=True,
        help="FILE.glb (all frames side by side) or FILE.ply (one file per frame)",
    )
    b = add_command(
        actions,
        "basis",
        "compute a mesh benchmark's spectral basis here and check it against the shipped one",
        basis,
    )
    b.add_argument("benchmark", help="mesh benchmark")
    b.add_argument("--data-root", help="dataset folder (default: the benchmark's)")
    b.add_argument(
        "--ship", action="store_true", help="write benchmarks/bases/ for a mesh with none shipped"
    )
    r = add_command(
        actions,
        "regressor",
        "fit a CMU-on-Anny benchmark's joint regressor here and compare it with the shipped one",
        regressor,
    )
    r.add_argument("benchmark", help="CMU-on-Anny benchmark")
    r.add_argument("--data-root", help="the CMU BVH folder (default: the benchmark's)")
    r.add_argument(
        "--ship",
        action="store_true",
        help="write benchmarks/regressors/ for a recipe with none shipped",
    )


def _dataset_arguments(p) -> None:
    p.add_argument("benchmark", help="benchmark whose dataset to use")
    p.add_argument("--split", help="split (default: the benchmark's test split; 'all': both)")
    p.add_argument("--data-root", help="dataset folder (default: the benchmark's)")


def _splits(args):
    from zoo.protocol.benchmark import get_benchmark

    bench = get_benchmark(args.benchmark)
    if args.split not in (None, "all", bench.split, bench.train_split):
        raise UsageError(
            f"--split {args.split!r}: benchmark {bench.name} has splits "
            f"{bench.split} (test) and {bench.train_split} (train), or 'all'"
        )
    splits = (
        [bench.split, bench.train_split] if args.split == "all" else [args.split or bench.split]
    )
    return bench, splits


def show(args) -> int:
    from tabulate import tabulate

    from zoo.protocol.benchmark import get_benchmark, list_benchmarks

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
                # none written: the loader's own (cloth generates its data) or --data-root
                str(b.resolve_data_root() or "(give --data-root, or the loader makes it)"),
            ]
        )
    headers = ["benchmark", "dataset", "representation", "test split", "train split",
               "data root"]  # fmt: skip
    print(tabulate(rows, headers=headers, tablefmt="github"))
    for line in _skipped_data(args.data_root):
        print(f"note: {line}")
    return 0


def describe_data(args) -> int:
    from tabulate import tabulate

    from zoo.data.catalog import describe

    bench, splits = _splits(args)
    for split in splits:
        dataset = bench.load(args.data_root, split=split)
        print(tabulate(list(describe(dataset).items()), tablefmt="plain"))
        print()
    return 0


def export(args) -> int:
    from zoo.data.catalog import export_window

    bench, splits = _splits(args)
    dataset = bench.load(args.data_root, split=splits[0])
    written = export_window(dataset, bench, args.window, args.out, sampler=args.sampler)
    print(
        f"wrote {', '.join(str(p) for p in written[:3])}"
        f"{f' and {len(written) - 3} more' if len(written) > 3 else ''}"
    )
    return 0


def basis(args) -> int:
    from zoo.protocol.benchmark import get_benchmark

    return _data_basis(get_benchmark(args.benchmark), args)


def regressor(args) -> int:
    from zoo.protocol.benchmark import get_benchmark

    return _data_regressor(get_benchmark(args.benchmark), args)


def _data_basis(bench, args) -> int:
    """``zoo data basis NAME``: the basis this machine computes for the benchmark's mesh,
    aligned to the shipped reference and checked against it; ``--ship`` writes the reference
    for a mesh that has none yet."""
    from zoo.data.spectral import check_basis_reference, reference_path, ship_basis_reference

    if bench.spectral_k is None:
        raise UsageError(f"benchmark {bench.name} has no spectral basis (no spectral_k)")
    topology = bench.load(args.data_root).topology
    path = reference_path(topology, bench.spectral_k)
    if not args.ship and not path.is_file():
        raise UsageError(
            f"no shipped basis reference for {bench.name} ({path}); zoo data basis "
            f"{bench.name} --ship writes one"
        )
    if args.ship:  # refused at once where a reference is shipped
        path, computed, took = ship_basis_reference(topology, bench.spectral_k)
        print(f"wrote {path} ({computed.solver}, {took:.1f} s)")
        return 0
    print(f"computing the basis of {topology.name} (k={bench.spectral_k}) ...", file=sys.stderr)
    check = check_basis_reference(topology, bench.spectral_k)
    report = check.report
    print(
        f"{bench.name}: basis {check.reference.hash[:12]} computed here in {check.seconds:.1f} s: "
        f"eigenvalues within {report['eigenvalues']:.2g} of the shipped reference, probe "
        f"projections within {report['misfit']:.2g} after alignment (worst: vectors "
        f"{report['worst_group']}): {'the same basis' if report['same'] else 'ANOTHER BASIS'}"
    )
    return 0 if report["same"] else 1


def _data_regressor(bench, args) -> int:
    """``zoo data regressor NAME``: fit the benchmark body's joint regressor here and compare it
    with the shipped one; ``--ship`` writes it for a recipe that has none yet."""
    import time

    from zoo.data import anny

    if bench.loader_function() is not anny.cmu_anny_dataset:
        raise UsageError(
            f"benchmark {bench.name} has no fitted joint regressor (only the CMU-on-Anny "
            f"benchmarks fit one)"
        )
    topology = bench.loader_options["topology"]
    root = args.data_root or bench.resolve_data_root()
    if root is None:
        raise UsageError(f"{bench.name}: give --data-root (the CMU BVH folder)")
    if args.ship:
        try:
            path, fitted = anny.ship_joint_regressor(root, topology)
        except anny.RegressorShippedError as e:
            raise UsageError(str(e)) from None
        print(f"wrote {path} ({fitted.matrix.nnz} weights; fit {fitted.recipe['fit_mean_mm']} mm)")
        return 0
    print(f"fitting the joint regressor of the {topology} Anny body ...", file=sys.stderr)
    started = time.perf_counter()
    report = anny.check_joint_regressor(root, topology)
    took = time.perf_counter() - started
    print(
        f"{bench.name}: joint regressor {report['path'].name} fitted here in {took:.1f} s: "
        f"weights within {report['weights']:.2g} of the shipped ones ({report['support'][0]} "
        f"against {report['support'][1]} non-zeros; a joint's row within "
        f"{report['rows_l1']:.2g} in L1), regressed joints on the fit's "
        f"{int(report['stats']['fit_frames'][0])} frames within {report['joints_mm']:.3g} mm "
        f"(mean {report['joints_mean_mm']:.2g} mm; tolerance {anny.REGRESSOR_TOLERANCE_MM} mm): "
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


def _skipped_data(data_root) -> list[str]:
    """Files and folders in the CMU data roots that the loader passes over (each once)."""
    from zoo.data.motion import CMU_ACTIONS, cmu_skipped
    from zoo.protocol.benchmark import get_benchmark, list_benchmarks

    lines = []
    for name in list_benchmarks():
        bench = get_benchmark(name)
        cmu = bench.loader == "zoo.data.motion:load_cmu"  # no other benchmark's code imported
        root = bench.resolve_data_root(data_root) if cmu else None
        if root is None or not root.is_dir():
            continue
        for split in dict.fromkeys((bench.split, bench.train_split)):
            for line in cmu_skipped(root, split, bench.actions or CMU_ACTIONS):
                entry = f"{root}/{line}"
                if entry not in lines:
                    lines.append(entry)
    return lines
