"""Pretrained weights and checkpoints: the typed records a run writes and reads back
(:mod:`.records`: a checkpoint's run record, and shipped weights' record), the weights format
(:mod:`.weights`, safetensors beside that record), checkpoint IO, export and the paused state
(:mod:`.checkpoints`), a registry model built for a benchmark (:mod:`.build`: its view and
constructor keywords), and where a row's model comes from (:mod:`.model_source`). It imports
store, models, protocol, data and core; never the evaluator or the training loop."""
