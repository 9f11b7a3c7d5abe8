"""Several processes (``torchrun``): which one this is, and how their shares come together.
Training uses it for data-parallel steps, the evaluator to split windows across processes."""

# zoo: computes no number

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any


@dataclass
class DistInfo:
    rank: int = 0
    world: int = 1

    @property
    def active(self) -> bool:
        return self.world > 1


def init_distributed(device: str = "cpu") -> DistInfo:
    """The process group ``torchrun`` describes (gloo on CPU, nccl on CUDA), or one process."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return DistInfo()
    import torch.distributed as dist

    if not dist.is_initialized():
        dist.init_process_group(backend="nccl" if str(device).startswith("cuda") else "gloo")
    return DistInfo(rank=dist.get_rank(), world=dist.get_world_size())


def gather_shares(share: dict[int, Any], info: DistInfo) -> dict[int, Any]:
    """Every process's ``{index: item}`` merged, in index order, on every process."""
    if not info.active:
        return dict(sorted(share.items()))
    import torch.distributed as dist

    shares: list = [None] * info.world
    dist.all_gather_object(shares, share)
    merged = {}
    for part in shares:
        merged.update(part)
    return dict(sorted(merged.items()))
