"""What a sampled check and a cost measurement spend by default: choices of how much to verify
or time, which move no number (so no row's identity records them), kept free of heavy imports
for the ``zoo`` command's help."""

# zoo: computes no number

# Windows a table's sampled check scores: a fault in 5% of a row's windows escapes it with
# probability 0.95**n (docs/reproducibility.md gives the sizes and times).
CHECK_WINDOWS = 32

# Seconds of measurement per model for the cost columns (zoo costs), so that the few
# architectures of a benchmark take a few minutes on two cores; a model slower than its budget
# goes over it by one warm-up and one timed call (or step).
COST_SECONDS = 30.0
