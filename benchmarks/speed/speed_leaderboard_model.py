"""What adding a researcher's model to a leaderboard costs beyond evaluating it.

Times, side by side in one run and in turn (``--repeats`` pairs), the two commands a researcher
runs for an outside model: ``zoo eval --sampler all`` of it, and ``zoo leaderboard --model M
--base RESULTS --results FOLDER`` (its rows on every table of the benchmark, beside the
committed ones, in a folder of one's own). Two probe models from outside the repository, each a
class file and a registry file written to a temporary folder: ``cheap`` (the last velocity
carried on) and ``rollout`` (a costly model that predicts ``--step`` frames a call and rolls its
prediction out in steps, each call a stack of matrix products, as TFAN does). Prints each
command's wall time and the ratio leaderboard / eval per probe.

Run: python benchmarks/speed/speed_leaderboard_model.py [--data-root ../shared/data/cmu_mocap]
     [--probes cheap rollout] [--repeats 1] [--work 64]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

PROBES = '''\
import torch
from torch import nn


class Cheap(nn.Module):
    """The last observed velocity carried on."""

    def __init__(self, input_frames, output_frames, num_points):
        super().__init__()
        self.output_frames = output_frames

    def forward(self, history):
        last, velocity = history[:, -1:], history[:, -1:] - history[:, -2:-1]
        steps = torch.arange(1, self.output_frames + 1, dtype=history.dtype).view(1, -1, 1, 1)
        return last + velocity * steps


class Rollout(nn.Module):
    """Predicts ``step`` frames a call from its last ``input_frames`` and rolls out: every call
    ``work`` products of a 512-wide layer (a costly model's forward pass)."""

    def __init__(self, input_frames, output_frames, num_points, step=5, work=64):
        super().__init__()
        self.t_in, self.t_out, self.step, self.work = input_frames, output_frames, step, work
        torch.manual_seed(0)
        self.mix = nn.Linear(512, 512)

    def forward(self, history):
        window, out = history, []
        while sum(o.shape[1] for o in out) < self.t_out:
            x = window[:, -self.t_in :]
            h = torch.zeros(x.shape[0], 512)
            for _ in range(self.work):
                h = torch.tanh(self.mix(h))
            velocity = x[:, -1:] - x[:, -2:-1]
            steps = torch.arange(1, self.step + 1, dtype=x.dtype).view(1, -1, 1, 1)
            frames = x[:, -1:] + velocity * steps + 0.0 * h.mean()
            out.append(frames)
            window = torch.cat([window, frames], dim=1)
        return torch.cat(out, dim=1)[:, : self.t_out]
'''

REGISTRY = """\
models:
  cheap:
    class: probes.py:Cheap
    representation: joints
    description: the last velocity carried on (a cheap probe)
  rollout:
    class: probes.py:Rollout
    representation: joints
    hparams: {{step: {step}, work: {work}}}
    description: a costly probe that rolls its prediction out in steps
"""


def timed(command: list[str], cwd: Path) -> float:
    started = time.perf_counter()
    done = subprocess.run(command, cwd=cwd, capture_output=True, text=True)
    seconds = time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    return seconds


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-root", default=str(REPO.parent / "shared" / "data" / "cmu_mocap"))
    parser.add_argument("--base", default=str(REPO / "results"), help="committed results")
    parser.add_argument("--probes", nargs="+", default=["cheap", "rollout"])
    parser.add_argument("--repeats", type=int, default=1, help="pairs timed per probe")
    parser.add_argument("--step", type=int, default=5, help="rollout: frames a call")
    parser.add_argument("--work", type=int, default=64, help="rollout: products a call")
    args = parser.parse_args(argv)
    zoo = [sys.executable, "-m", "zoo.cli"]
    env_note = f"{os.cpu_count()} CPUs, OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}"
    print(f"outside probes on cmu, data {args.data_root}, base {args.base} ({env_note})")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "probes.py").write_text(PROBES)
        (folder / "probes.yaml").write_text(REGISTRY.format(step=args.step, work=args.work))
        common = ["--registry", "probes.yaml", "--data-root", args.data_root]
        for probe in args.probes:
            evals, boards = [], []
            for i in range(args.repeats):
                out, results = folder / f"eval-{probe}-{i}", folder / f"results-{probe}-{i}"
                evals.append(
                    timed(
                        [*zoo, "eval", *common, "--model", probe, "--benchmark", "cmu",
                         "--sampler", "all", "--out", str(out)],
                        folder,
                    )
                )  # fmt: skip
                boards.append(
                    timed(
                        [*zoo, "leaderboard", *common, "--benchmark", "cmu", "--model", probe,
                         "--base", args.base, "--results", str(results),
                         "--checkpoints", str(folder / "no-checkpoints")],
                        folder,
                    )
                )  # fmt: skip
                shutil.rmtree(out)
                shutil.rmtree(results)
            e, b = statistics.median(evals), statistics.median(boards)
            print(
                f"{probe}: zoo eval --sampler all {e:.1f} s, zoo leaderboard --model --base "
                f"{b:.1f} s: ratio {b / e:.2f} (medians of {args.repeats})"
            )


if __name__ == "__main__":
    main()
