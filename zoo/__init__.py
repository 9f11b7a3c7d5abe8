"""motion-zoo: a model zoo and benchmark suite for 3D human motion prediction."""
__version__ = "0.1.0"

from zoo.api import create_model, list_models  # noqa: E402
from zoo.registry import load_registry  # noqa: E402

__all__ = ["__version__", "create_model", "list_models", "load_registry"]
