"""Choices and defaults that the library and the command line share, kept free of heavy
imports so that the ``zoo`` command can show them in its help without loading torch."""

# The evaluator's tasks: what a model is asked for.
TASKS = {
    "prediction": "the T_out frames after the observed ones",
    "completion": "in-betweening: the T_out frames after the observed ones, the last of them "
    "given to the model (final_frame)",
    "longterm": "long-term prediction: horizon frames, the model's predictions fed back as its "
    "next observed frames (autoregressive)",
}

# Windows per forward pass of the evaluator: small batches keep a model's tensors in the CPU's
# caches (docs/results.md, cost columns).
EVAL_BATCH = 64

# Windows a table's sampled check scores: a fault in 5% of a row's windows escapes it with
# probability 0.95**n (docs/reproducibility.md gives the sizes and times).
CHECK_WINDOWS = 32

# Seconds of measurement per model for the cost columns (zoo costs), so that the few
# architectures of a benchmark take a few minutes on two cores; a model slower than its budget
# goes over it by one warm-up and one timed call (or step).
COST_SECONDS = 30.0
