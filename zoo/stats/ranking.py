"""Which rows a table ranks: floors (``<model>:autoencoder``) and the ground truth's own row
are references beside the ranking, and a row with a missing horizon is left out of it, saying
why (:func:`unranked_reason`).
"""

# zoo: computes no number

from __future__ import annotations

import pandas as pd

from zoo.protocol.metrics import FLOOR_SUFFIX


def is_floor(model: str) -> bool:
    """Rows of a model's autoencoder floor, not a predictor."""
    return model.endswith(FLOOR_SUFFIX)


TRUTH_ROW = "ground_truth"  # the ground truth's own MELV (zoo.protocol.mesh): a reference


def unranked_reason(model: str, values: pd.Series) -> str | None:
    """Why a row of a view is no prediction to rank or bold: ``floor`` (an autoencoder floor,
    which sees the future), ``truth`` (the ground truth's own value) or ``zero`` (exactly 0 at
    every horizon: a held frame keeps every edge's length, so its MELV is 0 by construction);
    None for a predictor."""
    if is_floor(model):
        return "floor"
    if model == TRUTH_ROW:
        return "truth"
    if len(values) and (values.to_numpy(float) == 0).all():
        return "zero"
    return None
