"""Models of the zoo: plain ``torch.nn.Module`` classes, one file each, and what names them:
the registry (:mod:`.registry`, ``registry.yaml`` and a researcher's own), each entry's training
recipe (:mod:`.recipe`) and its paper and code (:mod:`.citation`). It imports data and core.

The common contract (all a model needs to be evaluated, trained and registered):

- constructor keywords ``input_frames``, ``output_frames`` and ``num_points`` (joints or
  vertices), which the benchmark supplies, plus the model's own hyper-parameters, whose
  defaults live in its ``registry.yaml`` entry;
- ``forward(history)`` takes the observed frames ``(B, T_in, P, 3)`` (float32, the dataset's
  units: mm for skeletons) and returns the predicted frames ``(B, T_out, P, 3)``. For skeleton
  benchmarks ``P`` is the set of predicted joints (CMU: 25), in the dataset's joint order;
- mesh benchmarks give vertices: ``(B, T_in, V, 3)`` in mm in, ``(B, T_out, V, 3)`` out;
- optional ``context`` keywords: a model that needs facts about the data names them in its
  registry entry under ``context`` and the benchmark provides them: ``parts`` (skeletons: the
  body-part split as indices into the predicted joints, SPGSN) and ``basis`` (meshes: the
  dataset's ``zoo.data.spectral.SpectralBasis``, SpecTrHuMS);
- completion models (registry ``task: completion``) take ``forward(history, final_frame)``,
  ``final_frame (B, P, 3)`` being the last of the ``T_out`` frames to fill in;
- optional hooks, each a ``typing.Protocol`` of :mod:`zoo.models.hooks`, read once by the
  engine and the evaluator with ``model_hooks`` (a model defining half a group is refused):
  ``training_loss`` (its own loss), ``start_epoch`` (a per-epoch step), the training view
  (``training_view``, ``training_view_identity``, ``training_loss_view``: a representation of
  the frames computed once and cached, SpecTrHuMS's coefficients), ``rollout`` (its own
  autoregression for long horizons) and ``autoencoder_floor`` (the ground truth through its
  autoencoder alone: the ``<name>:autoencoder`` rows of mesh tables).
"""
