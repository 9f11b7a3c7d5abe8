"""The zoo's error base: every error a user can cause derives from ZooError, so the command line
reports it as a one-line message while genuine bugs still show their traceback."""


class ZooError(Exception):
    """``parameter``: the argument of the library call the error is about, named as the library
    names it at the start of the message (``init_from: ...``); an interface may show its own
    name for it (the command line: its flag)."""

    def __init__(self, *args, parameter: str | None = None) -> None:
        super().__init__(*args)
        self.parameter = parameter


class DataNotFoundError(ZooError, FileNotFoundError):
    """A data root, file or folder that a benchmark needs does not exist."""


class EvaluationError(ZooError, RuntimeError):
    """A protocol that cannot be planned, a model that breaks the contract, a result folder that
    cannot be read."""


class TrainingError(ZooError, RuntimeError):
    """A recipe, data split or run that cannot train, or a training that went wrong."""
