"""What is measured, and how: a benchmark (:mod:`.benchmark`: its data, skeleton, frame rate
and samplers), what its kind of points owns (:mod:`.representation`, with :mod:`.joints` and
:mod:`.mesh`: loading checks, model inputs, the record, the ground truth, the training view), a
protocol planned once from it (:mod:`.plan`: which windows, which task, which
ground truth, and the record every row carries), the metrics (:mod:`.metrics`: MPJPE, MELV,
RMSE, each declared once with its tolerance and scoring, and their averaging), the views a
model sees a benchmark through and the metrics of each (:mod:`.views`: joints, mesh), whether
two records may share a table (:mod:`.comparable`), and the figures papers printed under a
protocol (:mod:`.published`). It imports only data and core."""
