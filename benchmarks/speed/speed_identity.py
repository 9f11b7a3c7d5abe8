"""How long a result's identity takes: the evaluator's code fingerprint computed from the files,
against the same fingerprint asked for again in the same process, side by side in one run.

A rebuild asks for the evaluator's fingerprint once per row and once per cost cell; the code
fingerprint keeps each module's pieces while neither it nor what they were resolved through
changes (:func:`zoo.store.fingerprint.module_pieces`). This prints, per benchmark:

- ``cold``: the fingerprint with every cache emptied, in memory and on disk (what the first
  process of a new checkout pays once);
- ``stored``: the caches in memory emptied, the pieces stored on disk by an earlier process
  kept (what every later process pays once);
- ``pieces anew``: the files' syntax trees kept, the pieces and the import scan recomputed
  and stored again (what each call cost before they were kept, and since the store on disk,
  its writes: not comparable with runs before it);
- ``kept``: the pieces kept, as every call after the first now is;
- the ratio ``pieces anew / kept``, and whether all three fingerprints agree (they must).

Then, per model, its fingerprint (the code its class reaches, asked for once per row and once
per cost key): ``reached anew`` (the module pieces kept, the class's reachable code recomputed:
what each call cost before it was kept) against ``kept``, and whether the two agree.

The store on disk is a temporary folder of this run's, not the checkout's.

Run: python benchmarks/speed/speed_identity.py [--benchmark NAME ...] [--model NAME ...]
[--repeats N]
"""

import argparse
import contextlib
import os
import shutil
import statistics
import tempfile
import time

from zoo.evaluation.pipeline import row_code
from zoo.models.registry import load_registry
from zoo.protocol.benchmark import get_benchmark
from zoo.store import fingerprint


def _timed(call, repeats: int) -> tuple[float, str]:
    times, value = [], None
    for _ in range(repeats):
        started = time.perf_counter()
        value = call()
        times.append(time.perf_counter() - started)
    return statistics.median(times), value


def _forget_stored() -> None:
    shutil.rmtree(fingerprint._store_folder(), ignore_errors=True)


def _forget_pieces() -> None:
    """What was not kept before: each module's pieces (in memory and on disk) and its import
    scan."""
    for key in [k for k in fingerprint._KEPT if k[0] == "pieces"]:
        del fingerprint._KEPT[key]
    _forget_stored()
    fingerprint._imported_names.cache_clear()
    fingerprint._imported_module_files.cache_clear()


def _forget_reached() -> None:
    for key in [k for k in fingerprint._KEPT if k[0] == "reachable"]:
        del fingerprint._KEPT[key]
    _forget_stored()


def _forget_memory() -> None:
    fingerprint._KEPT.clear()
    fingerprint._imported_names.cache_clear()
    fingerprint._imported_module_files.cache_clear()
    fingerprint._module_parts.cache_clear()
    fingerprint._syntax_tree.cache_clear()
    fingerprint._scan.cache_clear()


def measure(benchmark: str, repeats: int) -> dict:
    bench = get_benchmark(benchmark)

    def fingerprint_of() -> str:
        return row_code(None, bench)["evaluator"]

    def cold() -> str:
        _forget_memory()
        _forget_stored()
        return fingerprint_of()

    def stored() -> str:
        _forget_memory()
        return fingerprint_of()

    def anew() -> str:
        _forget_pieces()
        return fingerprint_of()

    cold_s, cold_value = _timed(cold, 1)
    stored_s, stored_value = _timed(stored, repeats)
    anew_s, anew_value = _timed(anew, repeats)
    fingerprint_of()  # the pieces kept from here on
    kept_s, kept_value = _timed(fingerprint_of, repeats)
    return {
        "benchmark": benchmark,
        "cold": cold_s,
        "stored": stored_s,
        "anew": anew_s,
        "kept": kept_s,
        "ratio": anew_s / kept_s,
        "same": cold_value == stored_value == anew_value == kept_value,
        "fingerprint": kept_value,
    }


def measure_model(name: str, repeats: int) -> dict:
    cls = load_registry().get(name).load_class()

    def anew() -> str:
        _forget_reached()
        return fingerprint.model_fingerprint(cls)

    fingerprint.model_fingerprint(cls)  # syntax trees and definition digests kept for both
    anew_s, anew_value = _timed(anew, repeats)
    fingerprint.model_fingerprint(cls)
    kept_s, kept_value = _timed(lambda: fingerprint.model_fingerprint(cls), repeats)
    return {
        "model": name,
        "anew": anew_s,
        "kept": kept_s,
        "ratio": anew_s / kept_s,
        "same": anew_value == kept_value,
        "fingerprint": kept_value,
    }


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--benchmark", nargs="+", default=["cmu", "cloth"])
    parser.add_argument("--model", nargs="+", default=["ltd", "spgsn", "spectrhums"])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as store, _cache_dir(store):
        return _measured(args)


@contextlib.contextmanager
def _cache_dir(folder: str):
    """``ZOO_CACHE_DIR`` set to ``folder`` while the block runs (the fingerprints' store then
    lives there), as it was after."""
    before = os.environ.get("ZOO_CACHE_DIR")
    os.environ["ZOO_CACHE_DIR"] = folder
    try:
        yield
    finally:
        if before is None:
            os.environ.pop("ZOO_CACHE_DIR")
        else:
            os.environ["ZOO_CACHE_DIR"] = before


def _measured(args) -> list[dict]:
    print(
        "benchmark  cold (s)  stored (s)  pieces anew (s)  kept (s)  cold/stored  anew/kept  "
        "fingerprints"
    )
    rows = []
    for name in args.benchmark:
        r = measure(name, args.repeats)
        rows.append(r)
        agree = f"agree ({r['fingerprint']})" if r["same"] else "DIFFER"
        print(
            f"{name:<10} {r['cold']:8.3f}  {r['stored']:10.3f}  {r['anew']:15.3f}  "
            f"{r['kept']:8.4f}  {r['cold'] / r['stored']:10.1f}x  {r['ratio']:8.0f}x  {agree}"
        )
    print("model        reached anew (s)  kept (s)  anew/kept  fingerprints")
    for name in args.model:
        r = measure_model(name, args.repeats)
        rows.append(r)
        agree = f"agree ({r['fingerprint']})" if r["same"] else "DIFFER"
        print(f"{name:<12} {r['anew']:16.3f}  {r['kept']:8.4f}  {r['ratio']:8.0f}x  {agree}")
    return rows


if __name__ == "__main__":
    main()
