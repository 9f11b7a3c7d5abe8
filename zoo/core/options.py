"""The evaluator's choices that the library and the command line share (a change here can move
numbers: this module is part of the evaluator's code identity), kept free of heavy imports so
that the ``zoo`` command can show them in its help without loading torch."""

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
