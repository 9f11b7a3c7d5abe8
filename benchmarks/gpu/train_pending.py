"""The pending CMU trainings (cmu, cmu50) on a lent GPU, in one go that stops before its limit.

Here, once (the compact CMU copy, which travels with the tree as an ignored path)::

    python benchmarks/gpu/train_pending.py pack            # -> cache/cmu_train.tar.xz (18 MB)

On the GPU machine (the device tool's command; weights/in_progress and the copy carried)::

    PYTHONPATH=. python3 benchmarks/gpu/train_pending.py run --out $OUT --minutes 8.5

Back here, the states it trained (replacing each model's committed paused state)::

    python benchmarks/gpu/train_pending.py unpack /work/.device/.../files

``run`` resumes each pending model (``--models``, each ``MODEL`` on ``cmu`` or
``BENCHMARK/MODEL``; the training queue by default) from its
committed paused state in ``weights/in_progress`` (or starts it), trains it with a CUDA-graph
step where capture works and eager otherwise, stops before ``--minutes`` are up (an epoch that
cannot finish in time is not begun; the last finished epoch is what is kept), and writes each
model's paused state to ``<out>/<model>/`` as ``state.tar.NN`` parts of at most 15 MiB (what the
device tool brings back), with the log in ``<out>/log.txt``. A model whose state would not fit
what comes back (8 files, 64 MiB) is not begun. On a CPU with ``--device cpu`` and
``--max-batches`` it runs the same way in minutes: the tests do so.
"""

from __future__ import annotations

import argparse
import io
import shutil
import sys
import tarfile
import tempfile
import time
from dataclasses import replace
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

# BENCHMARK/MODEL (a bare MODEL trains on cmu); cmu50 reads the same training files
# (cmu50/dmgnn, queued after these, is not here: its state, 313 MB, is more than a call returns).
# A finished run leaves: with no paused state, a model here would start again from epoch 1.
QUEUE = ("auxformer", "cmu50/tfan")
PACKED_DATA = REPO / "cache" / "cmu_train.tar.xz"
PART_BYTES = 15 * 2**20
RETURN_FILES, RETURN_BYTES = 8, 64 * 2**20  # what the device tool brings back from $OUT
# seconds kept free at the end: the last state compacted, split and written
WRITE_SECONDS = 30.0


def pack(args) -> int:
    """The CMU training split as one xz tar (the files themselves, so every sha256 holds)."""
    from zoo.core.io import atomic_path
    from zoo.protocol.benchmark import get_benchmark

    bench = get_benchmark("cmu")
    root = bench.resolve_data_root(args.data_root)
    with atomic_path(Path(args.out)) as tmp, tarfile.open(tmp, "w:xz") as tar:
        for name in ("MISSING.txt",):
            if (root / name).is_file():
                tar.add(root / name, arcname=name)
        for action in bench.actions:
            folder = root / bench.train_split / action
            if folder.is_dir():
                tar.add(folder, arcname=f"{bench.train_split}/{action}")
    print(f"wrote {args.out} ({Path(args.out).stat().st_size / 1e6:.1f} MB) from {root}")
    return 0


def _log(out: Path, text: str) -> None:
    print(text, flush=True)
    with open(out / "log.txt", "a") as f:
        f.write(text + "\n")


def _split_state(folder: Path, dest: Path) -> list[Path]:
    """A paused state's folder as one tar in parts of at most ``PART_BYTES``, each written
    whole (temporary name, then renamed), the tar's size and sha256 in the first part's name
    list (``state.tar.sha256``), so that ``unpack`` takes no part cut short."""
    import hashlib

    from zoo.core.io import atomic_path

    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as tar:
        for path in sorted(folder.iterdir()):
            tar.add(path, arcname=path.name)
    data = buffer.getvalue()
    dest.mkdir(parents=True, exist_ok=True)
    parts = []
    for i, start in enumerate(range(0, len(data), PART_BYTES)):
        parts.append(dest / f"state.tar.{i:02d}")
        with atomic_path(parts[-1]) as tmp:
            tmp.write_bytes(data[start : start + PART_BYTES])
    with atomic_path(dest / "state.tar.sha256") as tmp:
        tmp.write_text(f"{hashlib.sha256(data).hexdigest()} {len(data)} {len(parts)}\n")
    return [*parts, dest / "state.tar.sha256"]


def run(args) -> int:
    import torch

    started = time.time()
    stop_by = started + 60 * args.minutes - WRITE_SECONDS
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    device = args.device or ("cuda" if torch.cuda.is_available() else "cpu")
    name = torch.cuda.get_device_name() if device.startswith("cuda") else "CPU"
    _log(out, f"device {device} ({name}), torch {torch.__version__}, {args.minutes} min")
    work = Path(tempfile.mkdtemp(prefix="train_pending."))
    try:
        return _run_models(args, out, device, stop_by, started, work)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _run_models(args, out: Path, device: str, stop_by: float, started: float, work: Path) -> int:
    from zoo.core.errors import TrainingError
    from zoo.hub.checkpoints import pause_run
    from zoo.hub.weights import paused_dir, paused_runs
    from zoo.models.registry import load_registry
    from zoo.train.loop import train
    from zoo.train.options import RunOptions

    data = Path(args.data)
    if data.is_file():
        with tarfile.open(data) as tar:
            tar.extractall(work / "cmu", filter="data")
        data = work / "cmu"
    paused = paused_runs()
    files, size = 1, (out / "log.txt").stat().st_size
    for entry in args.models:
        bench, model = entry.split("/", 1) if "/" in entry else ("cmu", entry)
        summary = paused.get((bench, model))
        if summary and summary.get("finished"):
            _log(out, f"{model}: finished ({summary['epochs_run']} epochs); nothing to do")
            continue
        # what its state will weigh when it comes back: the committed one's, or its parameters'
        # (a paused state is about 5 bytes a parameter in last.pt and 2 in best.pt, which a
        # state whose best epoch was its last did not store but may bring back)
        expected = (
            sum(summary["files"].values())
            + (summary["files"]["last.pt"] // 2.5 if summary.get("best_is_last") else 0)
            if summary
            else 8 * _parameters(model, bench, args)
        )
        if files + int(expected // PART_BYTES) + 2 > RETURN_FILES or size + expected > RETURN_BYTES:
            _log(out, f"{model}: not begun, its state would not fit what comes back")
            continue
        if time.time() > stop_by:
            _log(out, f"{model}: not begun, no time left")
            continue
        run_dir = work / "runs" / model
        options = RunOptions(
            out_dir=run_dir,
            data_root=data,
            resume=summary is not None,
            seed=summary["seed"] if summary else 0,
            device=device,
            max_batches=args.max_batches,
            progress=False,
            stop_by=stop_by,
            cuda_graph=device.startswith("cuda"),
        )
        kw = dict(
            registry=load_registry(*(args.registry or ())),
            recipe_overrides={"precision": args.precision} if args.precision else None,
        )
        t0 = time.time()
        try:
            train(model, bench, options, **kw)
        except TrainingError as e:
            if "CUDA graph" not in str(e):
                raise
            _log(out, f"{model}: {e}; eager instead")
            train(model, bench, replace(options, cuda_graph=False), **kw)
        if not (run_dir / "last.pt").is_file():
            _log(out, f"{model}: no epoch finished in {time.time() - t0:.0f} s; nothing kept")
            continue
        state = pause_run(run_dir, root=work / "weights")
        parts = _split_state(state, out / model)
        files += len(parts)
        size += sum(p.stat().st_size for p in parts)
        parts = [p for p in parts if p.suffix != ".sha256"]
        done = paused_runs(work / "weights")[(bench, model)]
        _log(
            out,
            f"{model}: {done['epochs_run']} of {done['epochs_planned']} epochs, best "
            f"{done['best']['val_mpjpe']:.2f} mm at epoch {done['best']['epoch']}, "
            f"{time.time() - t0:.0f} s here; state in {len(parts)} part(s)",
        )
        assert paused_dir(bench, model, work / "weights") == state
    _log(out, f"done in {time.time() - started:.0f} s")
    return 0


def _parameters(model: str, bench: str, args) -> int:
    from zoo.models.registry import load_registry

    registry = load_registry(*(args.registry or ()))
    import zoo

    built = zoo.create_model(model, benchmark=bench, registry=registry)
    return sum(p.numel() for p in built.parameters())


def unpack(args) -> int:
    """Each ``<model>/state.tar.NN`` under ``args.folder`` into its committed paused state."""
    import hashlib

    from zoo.core.io import replace_folder
    from zoo.hub.weights import PAUSED_SUMMARY, paused_dir

    found = sorted({p.parent for p in Path(args.folder).glob("*/state.tar.00")})
    if not found:
        print(f"error: {args.folder}: no <model>/state.tar.00 to unpack", file=sys.stderr)
        return 1
    for folder in found:
        data = b"".join(p.read_bytes() for p in sorted(folder.glob("state.tar.[0-9][0-9]")))
        check = folder / "state.tar.sha256"
        digest, size, _ = check.read_text().split() if check.is_file() else ("", "0", "0")
        if hashlib.sha256(data).hexdigest() != digest:
            print(
                f"error: {folder}: its parts ({len(data)} bytes) are not the state written "
                f"({size} bytes, {check.name}): cut short or missing; nothing unpacked",
                file=sys.stderr,
            )
            return 1
        with tarfile.open(fileobj=io.BytesIO(data)) as tar:
            summary = json_of(tar, PAUSED_SUMMARY)
            dest = paused_dir(summary["benchmark"], summary["model"], args.weights_dir)
            with replace_folder(dest, markers=(PAUSED_SUMMARY,)) as tmp:
                tar.extractall(tmp, filter="data")
        print(f"{dest}: {summary['model']} after {summary['epochs_run']} epochs")
    return 0


def json_of(tar: tarfile.TarFile, name: str) -> dict:
    import json

    member = tar.extractfile(name)
    if member is None:
        raise SystemExit(f"error: the state holds no {name}")
    return json.loads(member.read())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    actions = parser.add_subparsers(dest="action", required=True)
    p = actions.add_parser("pack", help="the compact CMU copy (training split, xz)")
    p.add_argument("--data-root", help="CMU folder (default: the benchmark's)")
    p.add_argument("--out", default=str(PACKED_DATA), help="archive to write")
    r = actions.add_parser("run", help="train the pending models within --minutes")
    r.add_argument("--out", required=True, help="folder for states and log ($OUT)")
    r.add_argument("--minutes", type=float, default=8.5, help="the whole run's time limit")
    r.add_argument("--data", default=str(PACKED_DATA), help="the packed copy, or a CMU folder")
    r.add_argument("--models", nargs="+", default=list(QUEUE), help="in this order")
    r.add_argument("--device", help="default: cuda where there is one, else cpu")
    r.add_argument("--max-batches", type=int, help="cap batches per epoch (a quick check)")
    r.add_argument(
        "--precision",
        help="train in this precision (default: a resumed run's own, a new run's recipe's)",
    )
    r.add_argument("--registry", action="append", help="extra registry file (repeatable)")
    u = actions.add_parser("unpack", help="the states a run brought back, into weights/")
    u.add_argument("folder", help="the run's returned files (its --out)")
    u.add_argument("--weights-dir", help="weights folder (default: the repository's)")
    args = parser.parse_args(argv)
    return {"pack": pack, "run": run, "unpack": unpack}[args.action](args)


if __name__ == "__main__":
    sys.exit(main())
