"""SPGSN against a slow reference written from its equations (the paper's, in docs/models/spgsn.md).

The fast model batches everything (filters, tree channels, parts, blocks) into a few tensor
products, so an axis mix-up there (a softmax over the wrong axis, a weight transposed, a part's
nodes placed at the wrong body positions, a tree layer reusing the wrong weight) gives a model
that still trains but is not the paper's. The other SPGSN tests check shapes, the filter banks and
symmetries; none recomputes the forward pass. Here a reference does, one equation at a time, with
plain loops over samples, blocks, body parts, tree nodes, leaves and graph nodes, reading the
model's parameters by name, and in float64 so that agreement can be demanded to ~1e-9 (the
model computes in its own dtype, so a ``.double()`` copy runs in float64).

Checked:
- the model's prediction equals the reference's (float64 to 1e-9 relative, and the float32 model
  to float32 accuracy) for several tree shapes, with and without body parts;
- every parameter takes part: one backward pass of ``training_loss`` reaches each of them;
- the cross-part fusion is the stated one: the model differs clearly from the reference without
  fusion, with the fusion's two softmaxes swapped, and with the upper part reading the already
  updated lower part; and removing the model's fusion gives the reference without fusion.
"""

from __future__ import annotations

import copy

import pytest
import torch
from test_models_skeleton import motion

from zoo.models.spgsn import MM_PER_M, SPGSN, ScatteringBlock

INPUT_FRAMES, OUTPUT_FRAMES, DCT_N = 6, 4, 8  # dct_n < 10 frames: the truncation is exercised
POINTS = 8
# Unsorted (a part's graph rows follow its list), of different sizes (12 and 9 nodes: the two
# parts cannot be swapped silently, and a softmax over the wrong axis normalises over a different
# count), and joint 4 in no part: its node rows get nothing from the fusion.
PARTS = {"upper": [5, 0, 6, 3], "lower": [2, 7, 1]}
FUSIONS = ("paper", "none", "transposed", "sequential")


# ---- the reference ------------------------------------------------------------------------------


def dense(layer: torch.nn.Linear, x: torch.Tensor) -> torch.Tensor:
    """``x W^T + b`` of an ``nn.Linear``, written out."""
    y = x @ layer.weight.T
    return y if layer.bias is None else y + layer.bias


def part_rows(model: SPGSN, parts: dict | None) -> dict[str, list[int]]:
    """Node rows of each part: node ``3j + c`` is coordinate ``c`` of joint ``j``; a part's graph
    rows follow the order of its joint list."""
    rows = {"whole": list(range(3 * model.num_points))}
    if model.body_parts:
        for name in ("upper", "lower"):
            rows[name] = [3 * j + c for j in parts[name] for c in range(3)]
    return rows


def reference_filters(model: SPGSN, part: str, block: int) -> list[torch.Tensor]:
    """The paper's filters ``h_0 .. h_K`` of one block and part: ``A~ = (I + A / ||A||_F^2) / 2``,
    ``h_0 = a00 A``, ``h_1 = a10 I + a11 A~``, ``h_k = sum_{j=1..k} a_kj A~^(2^(j-1))``."""
    order = model.filter_order
    # The coefficient columns are the basis [A, I, A~, A~^2, A~^4, ...]: a00 is column 0, a10
    # column 1, a_kj (the weight of A~^(2^(j-1))) column j + 1. Only these may be used.
    used = [(0, 0)] + ([(1, 1), (1, 2)] if order >= 1 else [])
    used += [(k, j + 1) for k in range(2, order + 1) for j in range(1, k + 1)]
    expected_mask = torch.zeros_like(model.coefficient_mask)
    for entry in used:
        expected_mask[entry] = 1
    assert torch.equal(model.coefficient_mask, expected_mask)
    a = model.filter_coefficients[block]
    graph = model.graphs[part][block]
    eye = torch.eye(len(graph), dtype=graph.dtype)
    tilde = (eye + graph / (graph**2).sum()) / 2
    filters = [a[0, 0] * graph]
    if order >= 1:
        filters.append(a[1, 1] * eye + a[1, 2] * tilde)
    for k in range(2, order + 1):
        filters.append(
            sum(
                a[k, j + 1] * torch.linalg.matrix_power(tilde, 2 ** (j - 1))
                for j in range(1, k + 1)
            )
        )
    return filters


def scattering_leaves(
    block: ScatteringBlock, x: torch.Tensor, filters: list[torch.Tensor]
) -> list[torch.Tensor]:
    """The tree: every node ``U`` (the root is ``x``, node x channel) has the children
    ``tanh(h_k U W_k)``, one weight per layer and filter; returns the ``(K+1)^L`` leaves."""
    layer_weights = [[block.first_weight[:, k] for k in range(len(filters))]]
    layer_weights += [[w[k] for k in range(len(filters))] for w in block.deeper_weights]
    nodes = [x]
    for weights in layer_weights:
        children = []
        for u in nodes:
            for h_k, w_k in zip(filters, weights):
                children.append(torch.tanh(h_k @ u @ w_k))
        nodes = children
    return nodes


def spectrum_aggregation(block: ScatteringBlock, leaves: list[torch.Tensor]) -> torch.Tensor:
    """``H_sp = ReLU(mean_k(H_k) W_sp)``; leaf ``k`` of graph node ``n`` scores
    ``f2(tanh(f1([H_sp, H_k])))[n]``, ``f1`` on the concatenation being
    ``attention_sp(H_sp) + attention_leaf(H_k)``; each node's output is its leaves weighed by the
    softmax of their scores over the leaves (the channels)."""
    h_sp = torch.relu((sum(leaves) / len(leaves)) @ block.spectrum.weight.T)
    assert block.spectrum.bias is None  # W_sp is a plain matrix
    sp_term = dense(block.attention_sp, h_sp)
    scores = [
        dense(block.attention_out, torch.tanh(sp_term + dense(block.attention_leaf, h)))
        for h in leaves
    ]  # each (N_p, 1)
    out = torch.zeros_like(leaves[0])
    for n in range(len(out)):
        node_scores = torch.stack([s[n, 0] for s in scores])
        weights = torch.exp(node_scores - node_scores.max())
        weights = weights / weights.sum()
        for weight, h in zip(weights, leaves):
            out[n] += weight * h[n]
    return out


def fuse(
    block: ScatteringBlock, upper: torch.Tensor, lower: torch.Tensor, mode: str
) -> tuple[torch.Tensor, torch.Tensor]:
    """Bipartite fusion of one sample; affinity ``M = f_up(H_up) f_low(H_low)^T`` (upper x lower).

    ``paper``: each lower node takes the upper nodes weighed by the softmax of its column of M
    (over the upper nodes), each upper node the lower nodes weighed by the softmax of its row of M
    (over the lower nodes), both from the fusion's inputs, each added to the node's own features.
    The wrong variants the model must not match: ``none`` (no exchange), ``transposed`` (the two
    softmax axes swapped) and ``sequential`` (the upper part reads the already updated lower one).
    """
    if mode == "none":
        return upper, lower

    def embed(seq, x):  # f_up / f_low: Linear, ReLU, Linear (bias-free in the model)
        assert isinstance(seq[1], torch.nn.ReLU) and len(seq) == 3
        return dense(seq[2], torch.relu(dense(seq[0], x)))

    affinity = embed(block.embed_upper, upper) @ embed(block.embed_lower, lower).T
    over_upper, over_lower = torch.softmax(affinity, dim=0), torch.softmax(affinity, dim=1)
    if mode == "transposed":
        over_upper, over_lower = over_lower, over_upper
    new_lower = lower.clone()
    for lo in range(len(lower)):
        for u in range(len(upper)):
            new_lower[lo] += over_upper[u, lo] * upper[u]
    source = new_lower if mode == "sequential" else lower
    new_upper = upper.clone()
    for u in range(len(upper)):
        for lo in range(len(lower)):
            new_upper[u] += over_lower[u, lo] * source[lo]
    return new_upper, new_lower


def reference_block(
    block: ScatteringBlock,
    model: SPGSN,
    index: int,
    h: torch.Tensor,
    rows: dict[str, list[int]],
    fusion: str,
) -> torch.Tensor:
    """One block on one sample ``h`` (node x channel), without its skip connection:
    ``MLP(H_whole + (H_up' (+) H_low'))`` (dropout is off in eval mode)."""
    aggregated = {}
    for part, part_nodes in rows.items():
        leaves = scattering_leaves(block, h[part_nodes], reference_filters(model, part, index))
        aggregated[part] = spectrum_aggregation(block, leaves)
    combined = aggregated["whole"].clone()
    if model.body_parts:
        upper, lower = fuse(block, aggregated["upper"], aggregated["lower"], fusion)
        for features, part_nodes in ((upper, rows["upper"]), (lower, rows["lower"])):
            for i, node in enumerate(part_nodes):  # (+): back to the body positions
                combined[node] += features[i]
    linear, relu = block.mlp
    assert isinstance(relu, torch.nn.ReLU)
    return torch.relu(dense(linear, combined))


def reference_prediction(
    model: SPGSN, history: torch.Tensor, parts: dict | None, fusion: str = "paper"
) -> torch.Tensor:
    """The predicted frames ``(B, T_out, P, 3)``, one sample at a time: pad by repeating the
    last frame, DCT, keep ``dct_n`` coefficients (in ``model.unit``), embed (tanh), blocks with
    skips, readout added to the coefficients, inverse DCT."""
    assert fusion in FUSIONS
    rows = part_rows(model, parts)
    t_in, t_out = model.input_frames, model.output_frames
    predictions = []
    for sample in history:
        padded = torch.cat([sample, sample[-1:].expand(t_out, -1, -1)]).reshape(t_in + t_out, -1)
        coefficients = (model.dct @ padded).T  # (N, dct_n), node 3j + c
        h = torch.tanh(dense(model.embed, coefficients / model.unit))
        for index, block in enumerate(model.blocks):
            h = h + reference_block(block, model, index, h, rows, fusion)
        sequence = model.idct @ (coefficients + model.unit * dense(model.readout, h)).T
        predictions.append(sequence[t_in:].reshape(t_out, model.num_points, 3))
    return torch.stack(predictions)


# ---- helpers ------------------------------------------------------------------------------------


def make_model(
    body_parts: bool, layers: int = 2, order: int = 2, seed: int = 0, **overrides
) -> SPGSN:
    """A small SPGSN in which every path shows in the output: the zero-initialised readout and
    the diffusion-wavelet filter coefficients (many exact zeros and +-1) are randomised."""
    torch.manual_seed(seed)
    kwargs = dict(
        parts=PARTS if body_parts else None,
        body_parts=body_parts,
        blocks=2,
        hidden=8,
        scattering_layers=layers,
        filter_order=order,
        dct_n=DCT_N,
        aggregation_dim=4,
        fusion_dim=4,
        **overrides,
    )
    model = SPGSN(INPUT_FRAMES, OUTPUT_FRAMES, POINTS, **kwargs)
    with torch.no_grad():
        # a departure from repeat-last of order 100 mm, whichever unit the network works in
        model.readout.weight.normal_(std=0.03 * MM_PER_M / model.unit)
        model.readout.bias.normal_(std=0.001 * MM_PER_M / model.unit)
        # Entries outside coefficient_mask are randomised too: they must not matter.
        model.filter_coefficients.add_(0.3 * torch.randn_like(model.filter_coefficients))
        # At initialisation the parts' features differ little from node to node, so that the
        # fusion's affinity is flat (spread ~1e-4) and its softmaxes uniform: f_up and f_low
        # tenfold make the affinity spread of order one (the first block's weights up to ~0.2
        # where uniform is 1/12).
        for block in model.blocks if body_parts else ():
            for embedding in (block.embed_upper, block.embed_lower):
                embedding[0].weight.mul_(10.0)
                embedding[2].weight.mul_(10.0)
    return model.eval()


def as_float64(model: SPGSN) -> SPGSN:
    return copy.deepcopy(model).double()


def observed_motion(batch: int = 2) -> torch.Tensor:
    return motion(batch, INPUT_FRAMES, points=POINTS, seed=5).double()


def departure(prediction: torch.Tensor, observed: torch.Tensor) -> float:
    """Largest distance (mm) of a prediction from repeat-last: the scale of what the network
    adds."""
    return (prediction - observed[:, -1:]).abs().max().item()


def max_difference(a: torch.Tensor, b: torch.Tensor) -> float:
    return (a - b).abs().max().item()


# ---- 1. the forward pass ------------------------------------------------------------------------


@pytest.mark.parametrize(
    "layers, order, metre_inputs",
    [
        (2, 2, True),  # the paper's tree: 9 leaves
        (3, 1, True),  # a deeper tree (8 leaves): two deeper layers, each with its own weights
        (2, 3, False),  # h_3 = sum_j a_3j A~^(2^(j-1)), up to A~^4; coefficients in mm
        (1, 2, True),  # no deeper layer: the leaves are the first layer
    ],
)
@pytest.mark.parametrize("body_parts", [True, False])
def test_spgsn_forward_matches_the_equations(body_parts, layers, order, metre_inputs):
    model = make_model(body_parts, layers, order, metre_inputs=metre_inputs)
    observed = observed_motion()
    with torch.no_grad():
        fast32 = model(observed.float()).double()
        model64 = as_float64(model)
        fast = model64(observed)
        expected = reference_prediction(model64, observed, PARTS)
    scale = departure(expected, observed)
    assert scale > 5.0, f"the network barely moves the prediction ({scale} mm): a weak test"
    torch.testing.assert_close(fast, expected, rtol=1e-9, atol=1e-9 * scale)
    # The production dtype computes the same function, to float32 accuracy: positions of about
    # a metre carry ~2e-4 mm of rounding here, against departures of 40 to 200 mm.
    torch.testing.assert_close(fast32, expected, rtol=0, atol=2e-3)


# ---- 2. every parameter takes part --------------------------------------------------------------

# attention_out (f2) scores the leaves before a softmax over them; its bias shifts every score
# of a node equally, which the softmax cancels: its gradient is zero by construction.
SOFTMAX_INVARIANT = ("attention_out.bias",)


@pytest.mark.parametrize("body_parts", [True, False])
def test_one_backward_pass_reaches_every_parameter(body_parts):
    # float64: a gradient that is zero in exact arithmetic shows as round-off, below 1e-16 of
    # the largest, far under the smallest real one here (W_sp's, ~5e-8 of the largest: H_sp
    # enters only the leaf scores, through tanh and a softmax).
    model = as_float64(make_model(body_parts, layers=2, order=3))
    observed = observed_motion()
    future = motion(2, OUTPUT_FRAMES, points=POINTS, seed=6).double()
    model.training_loss(observed, future).backward()
    grads = {
        name: torch.zeros_like(p) if p.grad is None else p.grad
        for name, p in model.named_parameters()
    }
    zero = 1e-12 * max(g.abs().max().item() for g in grads.values())
    mask = model.coefficient_mask.bool()
    unreached, not_cancelled = [], []
    for name, grad in grads.items():
        if name == "filter_coefficients":
            # Entries outside the paper's terms are multiplied by zero; each of the others (per
            # block, filter and term) must be reached.
            assert grad[:, ~mask].abs().max() == 0, "coefficients outside the mask are used"
            missed = (grad[:, mask].abs() <= zero).sum().item()
            if missed:
                unreached.append(f"{name} ({missed} of the {grad[:, mask].numel()} used entries)")
        elif name.endswith(SOFTMAX_INVARIANT):
            if grad.abs().max() > zero:
                not_cancelled.append(name)
        elif grad.abs().max() <= zero:
            unreached.append(name)
    assert not unreached, f"no gradient reaches: {', '.join(unreached)}"
    assert not not_cancelled, f"expected to be cancelled by the leaf softmax: {not_cancelled}"


# ---- 3. the cross-part fusion -------------------------------------------------------------------


def test_fusion_is_the_stated_bipartite_exchange(monkeypatch):
    model = as_float64(make_model(body_parts=True))
    observed = observed_motion()
    with torch.no_grad():
        fast = model(observed)
        variants = {mode: reference_prediction(model, observed, PARTS, mode) for mode in FUSIONS}
        # The model's fusion switched off: its entry point returns the parts unchanged (if the
        # model's fusion entry point is renamed, follow it here).
        monkeypatch.setattr(ScatteringBlock, "_fuse", lambda self, upper, lower: (upper, lower))
        unfused = model(observed)
    scale = departure(variants["paper"], observed)
    torch.testing.assert_close(fast, variants["paper"], rtol=1e-9, atol=1e-9 * scale)
    for mode in ("none", "transposed", "sequential"):
        gap = max_difference(fast, variants[mode])
        # a clear margin: 0.1 % of what the network adds, 10^6 times the tolerance above
        assert gap > 1e-3 * scale, f"the model is as close to the {mode!r} fusion ({gap} mm)"
    # Removing the model's fusion changes its output, and leaves exactly the unfused reference.
    assert max_difference(unfused, fast) > 1e-3 * scale
    torch.testing.assert_close(unfused, variants["none"], rtol=1e-9, atol=1e-9 * scale)
