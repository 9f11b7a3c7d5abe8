"""Skeleton models: the DCT, the MLP baseline and SPGSN."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.fft
import torch

import zoo
from zoo.models.dct import dct_matrix, idct_matrix
from zoo.models.mlp import SiMLPe
from zoo.models.registry import RegistryError
from zoo.models.spgsn import SPGSN
from zoo.paths import REPO_ROOT

CMU_ROOT = (REPO_ROOT / "../shared/data/cmu_mocap").resolve()
SKELETON_MODELS = ["mlp", "spgsn", "spgsn_1body", "auxformer"]
# Small configurations for the tests that only need the wiring, not the paper's size.
SMALL = {
    "mlp": {"blocks": 4},
    "spgsn": {"blocks": 2, "hidden": 16, "aggregation_dim": 8},
    "spgsn_1body": {"blocks": 2, "hidden": 16, "aggregation_dim": 8},
    "auxformer": {"depth": 2, "width": 32, "mlp_dim": 32, "head_hidden": 32, "aux_head_hidden": 32},
}
CMU_PARTS = {"upper": list(range(10, 25)), "lower": list(range(10))}


def motion(batch: int, frames: int, points: int = 25, seed: int = 0) -> torch.Tensor:
    """Smooth random motion in mm: an offset per joint (up to ~1 m) plus a random walk, with
    some coordinates near zero so that absolute tolerances bite."""
    g = torch.Generator().manual_seed(seed)
    offsets = torch.randn(batch, 1, points, 3, generator=g) * 400
    offsets[:, :, :3] = torch.rand(batch, 1, 3, 3, generator=g)  # within 1 mm of the origin
    steps = torch.randn(batch, frames, points, 3, generator=g) * 5
    return offsets + steps.cumsum(dim=1)


# ---- DCT -----------------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 10, 35, 50])
def test_dct_matches_scipy_orthonormal_dct2(n):
    x = np.random.default_rng(n).normal(size=(n, 7))
    expected = scipy.fft.dct(x, type=2, norm="ortho", axis=0)
    np.testing.assert_allclose(dct_matrix(n, torch.float64).numpy() @ x, expected, atol=1e-12)
    np.testing.assert_allclose(dct_matrix(n).numpy() @ x, expected, atol=1e-5)


@pytest.mark.parametrize("n", [10, 35])
def test_dct_round_trip_is_exact(n):
    x = torch.randn(n, 75, generator=torch.Generator().manual_seed(n))
    d, d_inv = dct_matrix(n), idct_matrix(n)
    assert torch.equal(d_inv, d.T)
    assert torch.allclose(d_inv @ (d @ x), x, atol=1e-6, rtol=0)
    assert torch.allclose(d @ d_inv, torch.eye(n), atol=1e-6, rtol=0)
    # the inverse is scipy's orthonormal DCT-III
    np.testing.assert_allclose(
        d_inv.double().numpy() @ x.double().numpy(),
        scipy.fft.idct(x.double().numpy(), type=2, norm="ortho", axis=0),
        atol=1e-5,
    )


@pytest.mark.parametrize("n", [0, -3, 2.0, True])
def test_dct_rejects_bad_sizes(n):
    with pytest.raises(ValueError, match="positive integer"):
        dct_matrix(n)


# ---- MLP baseline (siMLPe) -----------------------------------------------------------------------


def test_untrained_mlp_is_repeat_last_to_a_micrometre_in_mm():
    model = zoo.create_model("mlp", benchmark="cmu").eval()
    history = motion(16, 10)
    with torch.no_grad():
        predicted = model(history)
    assert predicted.shape == (16, 25, 25, 3)
    deviation = (predicted - history[:, -1:]).abs().max().item()
    assert deviation <= 1e-6, deviation


def test_mlp_repeat_last_check_detects_a_non_tiny_gain():
    # The same check fails for a model that does not start near zero (the check can fail).
    model = SiMLPe(10, 25, 25, blocks=4, init_gain=1e-3).eval()
    history = motion(4, 10)
    with torch.no_grad():
        assert (model(history) - history[:, -1:]).abs().max().item() > 1e-6


def test_mlp_rolls_out_chunks_autoregressively():
    torch.manual_seed(0)
    model = SiMLPe(10, 25, 25, blocks=3, chunk=10, init_gain=1.0).eval()
    history = motion(3, 10)
    with torch.no_grad():
        predicted = model(history)
        first = model.step(history)
        second = model.step(first)  # the last 10 frames seen are exactly the first chunk
        third = model.step(second)
    assert torch.allclose(predicted, torch.cat([first, second, third[:, :5]], dim=1))
    assert (predicted[:, 10:] - predicted[:, 9:10]).abs().max() > 1.0  # a real, moving rollout


def test_mlp_chunk_is_at_most_the_observed_frames_and_sets_the_steps():
    model = SiMLPe(10, 25, 25, blocks=1, chunk=64)
    assert model.chunk == 10
    model = SiMLPe(10, 25, 25, blocks=1, chunk=5, init_gain=1.0).eval()
    calls = []
    original = model.step
    model.step = lambda window: calls.append(window.shape) or original(window)
    with torch.no_grad():
        assert model(motion(2, 10)).shape == (2, 25, 25, 3)
    assert len(calls) == 5


def test_mlp_training_loss_is_position_plus_velocity_l2_in_metres():
    torch.manual_seed(1)
    model = SiMLPe(10, 25, 25, blocks=2, init_gain=1.0)
    history, future = motion(4, 10, seed=1), motion(4, 25, seed=2)
    loss = model.training_loss(history, future)
    predicted = model.step(history) / 1000
    target = future[:, :10] / 1000
    position = (predicted - target).norm(dim=-1).mean()
    velocity = (predicted[:, 1:] - predicted[:, :-1]) - (target[:, 1:] - target[:, :-1])
    expected = position + velocity.norm(dim=-1).mean()
    assert loss.ndim == 0 and torch.allclose(loss, expected, rtol=1e-5)
    loss.backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in model.parameters())


def test_mlp_is_the_published_architecture():
    model = zoo.create_model("mlp", benchmark="cmu")
    assert len(model.blocks) == 48
    assert model.spatial_in.in_features == model.spatial_out.out_features == 75
    assert all(block.weight.shape == (10, 10) for block in model.blocks)  # T_in -> T_in
    assert all(block.norm.normalized_shape == (75,) for block in model.blocks)  # spatial axis
    assert not any(
        isinstance(m, (torch.nn.ReLU, torch.nn.GELU, torch.nn.Tanh)) for m in model.modules()
    )


def test_spgsn_is_paper_sized():
    """Paper Table 9 (H3.6M, 10 in / 10 out, dct_n 15): 5.66 M parameters. The widths the paper
    does not give (f_up / f_low, the block MLP) come from the authors' code; within 10%."""
    from zoo.data.skeleton import H36M

    parts = {k: list(v) for k, v in H36M.parts.items()}
    assert parts == {"upper": list(range(10, 22)), "lower": list(range(10))}  # the code's split
    model = zoo.create_model(
        "spgsn", input_frames=10, output_frames=10, num_points=22, parts=parts, dct_n=15
    )
    params = sum(p.numel() for p in model.parameters())
    assert abs(params / 5.66e6 - 1) < 0.10, params
    block = model.blocks[0]
    assert [tuple(m.weight.shape) for m in block.embed_upper if hasattr(m, "weight")] == [
        (64, 256),
        (64, 64),
    ]  # f_up: 256 -> 64 -> 64, bias-free
    assert block.embed_upper[0].bias is None


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"chunk": 0}, "chunk"),
        ({"blocks": -1}, "blocks"),
        ({"hidden_dim": 0}, "hidden_dim"),
        ({"init_gain": -1.0}, "init_gain"),
    ],
)
def test_mlp_rejects_bad_hyper_parameters(kwargs, message):
    with pytest.raises(ValueError, match=message):
        SiMLPe(10, 25, 25, **kwargs)


def test_mlp_rejects_wrong_input_shape():
    with pytest.raises(ValueError, match=r"history must have shape \(B, 10, 25, 3\)"):
        SiMLPe(10, 25, 25, blocks=1)(torch.zeros(2, 9, 25, 3))


# ---- SPGSN (paper design) ------------------------------------------------------------------------


def expected_filter_bank(graph: np.ndarray, a: np.ndarray) -> list[np.ndarray]:
    """The paper's filters, written out independently: A~ = (I + A / ||A||_F^2) / 2, h_0 = a00 A,
    h_1 = a10 I + a11 A~, h_k = sum_{j=1..k} a_kj A~^(2^(j-1)); a[k][j] is a_kj."""
    eye = np.eye(len(graph))
    tilde = (eye + graph / np.sum(graph**2)) / 2
    filters = [a[0][0] * graph, a[1][0] * eye + a[1][1] * tilde]
    for k in range(2, len(a)):
        filters.append(
            sum(a[k][j] * np.linalg.matrix_power(tilde, 2 ** (j - 1)) for j in range(1, k + 1))
        )
    return filters


@pytest.mark.parametrize("order", [2, 3])
def test_spgsn_filter_bank_at_initialisation_is_the_spec_polynomials(order):
    torch.manual_seed(order)
    model = SPGSN(
        4,
        3,
        3,
        parts={"upper": [0], "lower": [1, 2]},
        blocks=2,
        hidden=8,
        filter_order=order,
        dct_n=7,
    )
    # a00 = 1, a_k,k-1 = 1, a_kk = -1, all others 0
    a = [[1.0]] + [[0.0] * (k - 1) + [1.0, -1.0] for k in range(1, order + 1)]
    banks = model.filter_banks()
    assert set(banks) == {"whole", "upper", "lower"}
    for part, bank in banks.items():
        assert bank.shape == (2, order + 1, *model.graphs[part].shape[1:])
        for block in range(2):
            graph = model.graphs[part][block].detach().double().numpy()
            for k, h in enumerate(expected_filter_bank(graph, a)):
                np.testing.assert_allclose(bank[block, k].detach().numpy(), h, atol=1e-6)
    graph = model.graphs["whole"][0].detach().double().numpy()
    tilde = (np.eye(9) + graph / np.sum(graph**2)) / 2
    np.testing.assert_allclose(
        banks["whole"][0, 1].detach().numpy(), np.eye(9) - tilde, atol=1e-6
    )  # h_1 = I - A~
    np.testing.assert_allclose(
        banks["whole"][0, 2].detach().numpy(), tilde - tilde @ tilde, atol=1e-6
    )  # h_2 = A~ - A~^2


def test_spgsn_filter_bank_follows_trained_coefficients():
    torch.manual_seed(3)
    model = SPGSN(
        4, 3, 3, parts={"upper": [0], "lower": [1, 2]}, blocks=1, hidden=8, filter_order=3, dct_n=7
    )
    with torch.no_grad():
        model.filter_coefficients.normal_()  # entries outside the paper's terms must not matter
    c = model.filter_coefficients[0].detach().double().numpy()
    # column layout [A, I, A~, A~^2, A~^4]: a00 = c[0,0]; a10 = c[1,1]; a_kj = c[k, j+1]
    a = [[c[0, 0]], [c[1, 1], c[1, 2]]] + [
        [0.0] + [c[k, j + 1] for j in range(1, k + 1)] for k in range(2, 4)
    ]
    graph = model.graphs["lower"][0].detach().double().numpy()
    for k, h in enumerate(expected_filter_bank(graph, a)):
        np.testing.assert_allclose(
            model.filter_banks()["lower"][0, k].detach().numpy(), h, atol=1e-5
        )


def test_spgsn_scattering_tree_has_k_plus_1_to_the_l_leaves(monkeypatch):
    from zoo.models.spgsn import ScatteringBlock

    leaves = []
    original = ScatteringBlock._aggregate

    def recording(self, x):  # leaves (F, N_p, M, B, C): F * M channels
        leaves.append((x.shape[0] * x.shape[2], x.shape[1], x.shape[4]))
        return original(self, x)

    monkeypatch.setattr(ScatteringBlock, "_aggregate", recording)
    model = SPGSN(10, 25, 25, parts=CMU_PARTS, blocks=1, hidden=8, aggregation_dim=4).eval()
    with torch.no_grad():
        model(motion(2, 10))
    # (channels, nodes, features): whole body (75 nodes), upper (45), lower (30); 9 leaf
    # channels each (L = 2, K = 2)
    assert leaves == [(9, 75, 8), (9, 45, 8), (9, 30, 8)]


def test_spgsn_tanh_is_tanh_with_tanh_gradient():
    from zoo.models.spgsn import tanh

    x = (torch.randn(1000, dtype=torch.float32) * 4).requires_grad_()
    x_ref = x.detach().clone().requires_grad_()
    y, y_ref = tanh(x), torch.tanh(x_ref)
    torch.testing.assert_close(y, y_ref, atol=3e-7, rtol=0)
    g = torch.randn(1000)
    y.backward(g)
    y_ref.backward(g)
    torch.testing.assert_close(x.grad, x_ref.grad, atol=1e-6, rtol=1e-5)


def relabelled_copy(model: SPGSN, perm: list[int], parts: dict) -> tuple[SPGSN, dict]:
    """The same model for joints relabelled so that new joint i is old joint perm[i]: body-part
    lists in the new labels (sorted, so the part's own node order changes too) and every learned
    graph relabelled the same way."""
    inverse = {old: new for new, old in enumerate(perm)}
    new_parts = {name: sorted(inverse[j] for j in joints) for name, joints in parts.items()}
    state = model.state_dict()

    def node_order(old_joints_in_new_order, old_part):
        local = {j: i for i, j in enumerate(old_part)}
        return torch.tensor([3 * local[j] + c for j in old_joints_in_new_order for c in range(3)])

    whole = node_order(perm, range(model.num_points))
    state["graphs.whole"] = state["graphs.whole"][:, whole][:, :, whole]
    for name, joints in new_parts.items():
        order = node_order([perm[j] for j in joints], parts[name])
        state[f"graphs.{name}"] = state[f"graphs.{name}"][:, order][:, :, order]
    copy = SPGSN(
        model.input_frames,
        model.output_frames,
        model.num_points,
        parts=new_parts,
        blocks=len(model.blocks),
        hidden=model.embed.out_features,
        aggregation_dim=model.blocks[0].attention_leaf.out_features,
        dct_n=model.dct_n,
    )
    copy.load_state_dict(state)
    return copy.eval(), new_parts


def test_relabelling_the_joints_relabels_spgsn_output_and_nothing_else():
    torch.manual_seed(7)
    parts = {"upper": [3, 0, 7, 5], "lower": [1, 2, 4, 6, 8]}  # unsorted, joint 9 in no part
    model = SPGSN(10, 25, 10, parts=parts, blocks=2, hidden=16, aggregation_dim=8).eval()
    with torch.no_grad():
        model.readout.weight.normal_(std=0.1)  # a network that does something
    perm = torch.randperm(10, generator=torch.Generator().manual_seed(1)).tolist()
    relabelled, new_parts = relabelled_copy(model, perm, parts)
    history = motion(4, 10, points=10)
    with torch.no_grad():
        predicted = model(history)
        predicted_relabelled = relabelled(history[:, :, perm])
        untouched_graphs = SPGSN(
            10, 25, 10, parts=new_parts, blocks=2, hidden=16, aggregation_dim=8
        ).eval()
        untouched_graphs.load_state_dict(model.state_dict())
        wrong = untouched_graphs(history[:, :, perm])
    assert (predicted - history[:, -1:]).abs().max() > 10  # not a trivial output
    torch.testing.assert_close(predicted_relabelled, predicted[:, :, perm], atol=1e-3, rtol=1e-5)
    # the check can fail: graphs left in the old labels give a different prediction
    assert (wrong - predicted[:, :, perm]).abs().max() > 1.0


def test_spgsn_with_all_coefficients_and_zero_readout_is_repeat_last():
    # Untrained (zero readout) SPGSN returns the inverse DCT of the padded input's kept
    # coefficients; with every coefficient kept that is exactly repeat-last.
    model = SPGSN(
        10, 25, 25, parts=CMU_PARTS, blocks=1, hidden=8, dct_n=35, zero_readout=True
    ).eval()
    history = motion(3, 10)
    with torch.no_grad():
        assert torch.allclose(model(history), history[:, -1:].expand(-1, 25, -1, -1), atol=1e-3)
        truncated = SPGSN(
            10, 25, 25, parts=CMU_PARTS, blocks=1, hidden=8, dct_n=30, zero_readout=True
        ).eval()
        padded = torch.cat([history, history[:, -1:].expand(-1, 25, -1, -1)], dim=1)
        d = dct_matrix(35)[:30]
        expected = d.T @ (d @ padded[0].reshape(35, 75))
        assert torch.allclose(
            truncated.reconstruct(history)[0].reshape(35, 75), expected, atol=1e-3
        )
        assert (expected - padded[0].reshape(35, 75)).abs().max() > 0.1  # truncation shows


def test_spgsn_training_loss_is_mean_joint_error_over_all_frames():
    torch.manual_seed(2)
    model = SPGSN(10, 25, 25, parts=CMU_PARTS, blocks=1, hidden=8, dropout=0.0)
    with torch.no_grad():
        model.readout.weight.normal_(std=0.1)
    history, future = motion(2, 10), motion(2, 25, seed=3)
    loss = model.training_loss(history, future)
    target = torch.cat([history, future], dim=1)
    expected = (model.reconstruct(history) - target).norm(dim=-1).mean()
    assert loss.shape == () and torch.allclose(loss, expected)


def test_spgsn_paper_configuration():
    model = zoo.create_model("spgsn", benchmark="cmu")
    assert len(model.blocks) == 10 and model.embed.out_features == 256 and model.dct_n == 30
    assert model.blocks[0].layers == 2 and model.blocks[0].filters == 3
    assert model.blocks[0].dropout.p == 0.5
    assert {k: tuple(v.shape) for k, v in model.graphs.items()} == {
        "whole": (10, 75, 75),
        "upper": (10, 45, 45),
        "lower": (10, 30, 30),
    }
    whole_body = zoo.create_model("spgsn_1body", benchmark="cmu")
    assert set(whole_body.graphs) == {"whole"}
    assert not hasattr(whole_body.blocks[0], "embed_upper")


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (
            {"parts": {"upper": [0, 25], "lower": [1]}},
            r"parts\['upper'\] holds 25; expected joint "
            r"indices in 0..24",
        ),
        ({"parts": {"upper": [0, 1], "lower": [1]}}, "must be disjoint"),
        ({"parts": {"upper": [0]}}, "exactly the keys 'upper' and 'lower'"),
        ({"parts": {"upper": [], "lower": [1]}}, r"parts\['upper'\] is empty"),
        ({"parts": None}, "parts must be a mapping"),
        ({"parts": CMU_PARTS, "dct_n": 36}, "dct_n = 36 exceeds the 35 frames"),
        ({"parts": CMU_PARTS, "dropout": 1.0}, "dropout"),
        ({"parts": CMU_PARTS, "scattering_layers": 0}, "scattering_layers"),
    ],
)
def test_spgsn_rejects_bad_arguments(kwargs, message):
    with pytest.raises(ValueError, match=message):
        SPGSN(10, 25, 25, **{"blocks": 1, "hidden": 8, **kwargs})


# ---- every skeleton model: registry, contract, evaluator ---------------------------------------


@pytest.mark.parametrize("name", SKELETON_MODELS)
def test_registered_model_follows_the_contract(name):
    entry = zoo.load_registry().get(name)
    assert entry.trainable and "joints" in entry.representation
    assert {
        "optimizer",
        "lr",
        "weight_decay",
        "batch_size",
        "epochs",
        "grad_clip",
        "schedule",
        "augment",
    } <= set(entry.train)
    model = zoo.create_model(name, benchmark="cmu", **SMALL[name])
    history, future = motion(3, 10), motion(3, 25, seed=5)
    predicted = model.eval()(history)
    assert predicted.shape == (3, 25, 25, 3) and predicted.dtype == torch.float32
    assert torch.isfinite(predicted).all()
    loss = model.train().training_loss(history, future)
    assert loss.ndim == 0 and torch.isfinite(loss)
    loss.backward()


@pytest.mark.parametrize("name", SKELETON_MODELS)
def test_unknown_hyper_parameter_is_an_error(name):
    with pytest.raises(RegistryError, match="no hyper-parameter 'hiden'"):
        zoo.create_model(name, benchmark="cmu", hiden=3)


@pytest.fixture(scope="module")
def cmu_test_data():
    if not (CMU_ROOT / "test").is_dir():
        pytest.skip(f"CMU Mocap test data not found at {CMU_ROOT}")
    from zoo.protocol.benchmark import get_benchmark

    return get_benchmark("cmu").load(CMU_ROOT)


@pytest.fixture(scope="module")
def repeat_last_result(cmu_test_data):
    return zoo.evaluate(
        zoo.create_model("repeat_last", benchmark="cmu"),
        "cmu",
        label="repeat_last",
        dataset=cmu_test_data,
    )


@pytest.mark.parametrize("name", SKELETON_MODELS)
def test_models_evaluate_on_real_cmu_test_data(name, cmu_test_data, repeat_last_result):
    torch.manual_seed(0)
    model = zoo.create_model(name, benchmark="cmu", **SMALL[name])
    result = zoo.evaluate(model, "cmu", label=name, dataset=cmu_test_data)
    frame, reference = result.frame, repeat_last_result.frame
    assert len(frame) == len(reference) > 0
    assert np.isfinite(frame["value"]).all() and (frame["value"] > 0).all()
    assert result.protocol["protocol_id"] == repeat_last_result.protocol["protocol_id"]
    if name == "mlp":  # untrained: repeat-last, so the same table to float rounding
        np.testing.assert_allclose(frame["value"], reference["value"], atol=1e-4)


@pytest.mark.slow
@pytest.mark.parametrize(
    "name, overrides, lr",
    [
        ("mlp", {}, 3e-4),
        ("spgsn", {"blocks": 2, "hidden": 64}, 1e-3),
        ("spgsn_1body", {"blocks": 2, "hidden": 64}, 1e-3),
    ],
)
def test_models_learn_on_cmu_training_windows(name, overrides, lr):
    """150 Adam steps on real CMU training windows take the model below repeat-last."""
    if not (CMU_ROOT / "train").is_dir():
        pytest.skip(f"CMU Mocap training data not found at {CMU_ROOT}")
    from zoo.data.windows import gather_windows, window_sampler
    from zoo.protocol.benchmark import get_benchmark

    data = get_benchmark("cmu").load(CMU_ROOT, split="train")
    index = window_sampler("stride5", [len(s) for s in data.sequences], 10, 25, data.ltd_rule)
    windows = torch.from_numpy(gather_windows([s.positions for s in data.sequences], index, 35))
    windows = windows[:, :, list(data.skeleton.used)].float()
    held_out = windows[::50]
    torch.manual_seed(0)
    model = zoo.create_model(name, benchmark="cmu", **overrides).train()
    optimizer = torch.optim.Adam(model.parameters(), lr)
    generator = torch.Generator().manual_seed(0)
    for _ in range(150):
        batch = windows[torch.randint(0, len(windows), (32,), generator=generator)]
        loss = model.training_loss(batch[:, :10], batch[:, 10:])
        optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        optimizer.step()
    with torch.no_grad():
        error = (model.eval()(held_out[:, :10]) - held_out[:, 10:]).norm(dim=-1).mean()
    repeat_last = (held_out[:, 9:10] - held_out[:, 10:]).norm(dim=-1).mean()
    assert error < 0.95 * repeat_last, (error.item(), repeat_last.item())
