"""The zoo's error base: every error a user can cause derives from ZooError, so the command line
reports it as a one-line message while genuine bugs still show their traceback."""

# zoo: computes no number


class ZooError(Exception):
    pass


class NamesParameter:
    """An error about one argument of a library call (``parameter``), which the message names
    as the library does, at its start (``init_from: ...``); an interface may show its own name
    for it (the command line: its flag). Kept out of ZooError, whose definition every model's
    error class reaches (and so every model's code fingerprint)."""

    def __init__(self, *args, parameter: str | None = None) -> None:
        super().__init__(*args)
        self.parameter = parameter


class DataNotFoundError(ZooError, FileNotFoundError):
    """A data root, file or folder that a benchmark needs does not exist."""


class BenchmarkError(ZooError, ValueError):
    """A benchmark file, or what its loader returned, is not what the zoo can plan with."""


class EvaluationError(ZooError, RuntimeError):
    """A protocol that cannot be planned, a model that breaks the contract, a result folder that
    cannot be read."""


class TrainingError(NamesParameter, ZooError, RuntimeError):
    """A recipe, data split or run that cannot train, or a training that went wrong."""
