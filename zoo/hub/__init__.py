"""Pretrained weights and checkpoints: the weights format and its record (:mod:`.weights`,
safetensors beside a JSON record), checkpoint IO, export and the paused state
(:mod:`.checkpoints`), a registry model built for a benchmark (:mod:`.build`: its view and
constructor keywords), and where a row's model comes from (:mod:`.model_source`). It imports
store, models, protocol, data and core; never the evaluator or the training loop."""
