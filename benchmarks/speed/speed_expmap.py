"""How long reading exp-map text takes: numpy's C reader (what ``read_expmap_file`` runs) against
the line-by-line reading it falls back to for a file it refuses (Python's ``str.split``, then
numpy converting the strings), side by side in one run on the same texts.

Every ``.txt`` file under the data root (CMU Mocap by default, Human3.6M's layout too) is read
from disk once; each repeat parses all the texts with one reader, then with the other, which goes
first alternating, so that a change of load hits both alike. Prints the files, frames and values,
each reader's median time over the repeats, their ratio, and whether the two give the same
float64 bits for every file (they must).

Run: python benchmarks/speed/speed_expmap.py [--data-root DIR] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from zoo.data.expmap import _frames_by_line, _parsed
from zoo.data.skeleton import CMU, H36M
from zoo.paths import REPO_ROOT


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-root", type=Path, default=REPO_ROOT.parent / "shared" / "data")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    texts = []
    for path in sorted(args.data_root.rglob("*.txt")):
        text = path.read_text()
        first = text.split("\n", 1)[0].count(",") + 1
        skeleton = next((s for s in (CMU, H36M) if s.num_channels == first), None)
        if skeleton is not None:
            texts.append((path, text, skeleton))
    if not texts:
        raise SystemExit(f"speed_expmap: no exp-map .txt file under {args.data_root}")
    readers = {
        "numpy's reader": lambda path, text, skeleton: _parsed(text, skeleton.num_channels),
        "line by line": _frames_by_line,
    }
    times: dict[str, list[float]] = {name: [] for name in readers}
    frames: dict[str, list[np.ndarray]] = {}
    for repeat in range(args.repeats):
        order = list(readers) if repeat % 2 == 0 else list(readers)[::-1]
        for name in order:
            started = time.perf_counter()
            frames[name] = [readers[name](*item) for item in texts]
            times[name].append(time.perf_counter() - started)
    same = all(
        a is not None and a.tobytes() == b.tobytes()
        for a, b in zip(frames["numpy's reader"], frames["line by line"])
    )
    fast, slow = (statistics.median(times[name]) for name in readers)
    count = sum(len(f) for f in frames["line by line"])
    values = sum(f.size for f in frames["line by line"])
    print(f"{len(texts)} files, {count:,} frames, {values:,} values (median of {args.repeats}):")
    print(f"  numpy's reader {fast:.3f} s, line by line {slow:.3f} s, ratio {slow / fast:.2f}")
    print(f"  the same float64 bits for every file: {'yes' if same else 'NO'}")
    return {"fast": fast, "slow": slow, "ratio": slow / fast, "same": same}


if __name__ == "__main__":
    main()
