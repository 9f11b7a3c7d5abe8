"""motion-zoo: a model zoo and benchmark suite for 3D human motion prediction.

The API (:mod:`zoo.api`) is loaded on first use, so ``import zoo`` and the ``zoo`` command's
help do not import torch.
"""

# zoo: computes no number

from zoo.core.version import __version__

_API = ("compare", "create_model", "evaluate", "list_models", "load_results")

__all__ = ["__version__", *_API, "load_registry"]


def __getattr__(name: str):
    if name in _API:
        import zoo.api

        return getattr(zoo.api, name)
    if name == "load_registry":
        from zoo.models.registry import load_registry

        return load_registry
    raise AttributeError(f"module 'zoo' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
