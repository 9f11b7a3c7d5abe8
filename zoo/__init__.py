"""motion-zoo: a model zoo and benchmark suite for 3D human motion prediction."""

import inspect as _inspect
import sys as _sys
import types as _types

import zoo.compare  # noqa: E402
import zoo.evaluate  # noqa: E402
from zoo.api import create_model, list_models, load_results  # noqa: E402
from zoo.registry import load_registry  # noqa: E402
from zoo.version import __version__  # noqa: E402


class _CallableModule(_types.ModuleType):
    """``zoo.evaluate`` and ``zoo.compare`` are modules (``from zoo.evaluate import evaluate``)
    and the API's functions (``zoo.evaluate(model, "cmu")``) at once: calling the module calls
    :mod:`zoo.api`'s function of the same name."""

    def __call__(self, *args, **kwargs):
        return getattr(_sys.modules["zoo.api"], self.__name__.rsplit(".", 1)[1])(*args, **kwargs)


for _module in (zoo.evaluate, zoo.compare):
    _module.__class__ = _CallableModule
    # inspect.signature (and editors) show the API function's parameters
    _module.__signature__ = _inspect.signature(
        getattr(_sys.modules["zoo.api"], _module.__name__[4:])
    )

__all__ = [
    "__version__",
    "compare",
    "create_model",
    "evaluate",
    "list_models",
    "load_results",
    "load_registry",
]
