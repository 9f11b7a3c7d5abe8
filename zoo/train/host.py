"""Facts about the machine a run trains on, which its record keeps: the CPU's name and
whether it multiplies bfloat16 natively, the device's name, the machines of a resumed run."""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Any

import torch


def cpu_info(path: str | Path = "/proc/cpuinfo") -> dict[str, str]:
    """The first processor's fields of ``path`` (Linux), or {} where it cannot be read."""
    try:
        text = Path(path).read_text()
    except OSError:
        return {}
    info: dict[str, str] = {}
    for line in text.splitlines():
        key, sep, value = line.partition(":")
        if not sep:
            if info:  # a blank line ends the first processor
                break
            continue
        info.setdefault(key.strip(), value.strip())
    return info


def cpu_has_native_bfloat16(cpuinfo: str | Path = "/proc/cpuinfo") -> bool | None:
    """Whether this CPU multiplies bfloat16 natively (AVX512-BF16 or AMX), from the flags of
    ``cpuinfo``; None where they cannot be read (not Linux). Without them a bfloat16 autocast
    runs its products on a slow fallback."""
    flags = cpu_info(cpuinfo).get("flags")
    return None if flags is None else bool({"avx512_bf16", "amx_bf16"} & set(flags.split()))


def precision_on(precision: str, device, native: bool | None = None) -> str:
    """A recipe's ``precision`` as a run on ``device`` takes it: ``auto`` is bfloat16 on a CPU
    that multiplies it natively (``native``; read from this CPU's flags where None) and float32
    elsewhere (a GPU, another CPU); any other precision is itself."""
    if precision != "auto":
        return precision
    if torch.device(device).type != "cpu":
        return "float32"
    native = _this_cpu_has_native_bfloat16() if native is None else native
    return "bfloat16" if native else "float32"


@functools.cache
def _this_cpu_has_native_bfloat16() -> bool:
    return cpu_has_native_bfloat16() is True  # read once: a step asks on every call


def device_name(device) -> str:
    if str(device).startswith("cuda") and torch.cuda.is_available():
        return torch.cuda.get_device_name(torch.device(device))
    import platform

    # the model and the kernels torch picked (AVX2, AVX512, ...): a budget in minutes, and
    # whether mixed precision pays, depend on both
    model = cpu_info().get("model name") or platform.processor() or "CPU"
    return (
        f"CPU {model} ({platform.machine()}, {torch.backends.cpu.get_cpu_capability()}), "
        f"{os.cpu_count()} cores"
    )


def devices_text(history: list[dict[str, Any]], current: str) -> str:
    """The machines a run's epochs ran on: one name, or each with its epochs and minutes
    (``NVIDIA H200: epochs 1-7, 8.7 min; CPU ...: epochs 8-50, ...``). An epoch recorded
    before epochs named their device counts as ``current``'s."""
    spans: list[list] = []  # [name, first epoch, last epoch, seconds]
    for i, h in enumerate(history, 1):
        name = h.get("device") or current
        if spans and spans[-1][0] == name:
            spans[-1][2], spans[-1][3] = i, spans[-1][3] + h["seconds"]
        else:
            spans.append([name, i, i, h["seconds"]])
    if len({s[0] for s in spans}) <= 1:
        return spans[0][0] if spans else current
    return "; ".join(
        f"{name}: epoch{'s' if a != b else ''} {a}{f'-{b}' if a != b else ''}, "
        f"{seconds / 60:.1f} min"
        for name, a, b, seconds in spans
    )
