"""The one evaluator and the path of one result: the pass that scores models over a planned
protocol's windows (:mod:`.evaluator`), a result read and written (:mod:`.results`) with its
Markdown (:mod:`.markdown`), how close a recomputed number must be to the stored one
(:mod:`.tolerance`), and the pipeline from a model to a stored, stamped result
(:mod:`.pipeline`). It imports hub, store, models, protocol, data and core."""
