"""The base every other package may import: ``errors`` (the errors a command turns into one
line), ``version``, ``options`` (the evaluator's choices the CLI shows without loading torch)
and ``budgets`` (what a sampled check or a cost measurement spends by default); above those,
``io`` (atomic writes, folder locks, hashes, progress bars) and ``distributed`` (the process
group ``torchrun`` describes). It imports no zoo module but :mod:`zoo.paths`, which stays at
the package's top: its one line computes the repository's root from its own place, so moving
it would change code every row's identity reaches."""
