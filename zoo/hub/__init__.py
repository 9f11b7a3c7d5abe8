"""Pretrained weights and checkpoints: the weights format and its record (:mod:`.weights`,
safetensors beside a JSON record), checkpoint IO, export and the paused state
(:mod:`.checkpoints`), and where a model's weights come from for a row (:mod:`.model_source`).
It imports store, models, protocol, data and core; never the evaluator or the training loop."""
