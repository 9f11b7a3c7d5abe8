"""SpecTrHuMS with anchored inference (the zoo's change): its frames, and running the paper
entry's weights through the registry's ``weights_of``."""

import pytest
import torch
from test_spectrhums import BASIS, SMALL, T_IN, T_OUT, V, motion, trained_stats

from zoo.models.registry import Registry, RegistryError, load_registry
from zoo.models.spectrhums import SpecTrHuMS, SpecTrHuMSError
from zoo.models.spectrhums_anchored import AnchoredSpecTrHuMS


def anchored(seed=0, **kw):
    torch.manual_seed(seed)
    return trained_stats(AnchoredSpecTrHuMS(T_IN, T_OUT, V, BASIS, **{**SMALL, **kw})).eval()


def test_each_frame_is_the_last_observed_plus_the_decoded_change_from_it():
    model = anchored()
    history = motion(3)[:, :T_IN]
    with torch.no_grad():
        # the paper's steps, by hand: encode, standardise, fill, transform, decode
        z = model.standardise_latents(model.encode(model.project(history)))
        out = model.transformer(torch.cat([z, z[:, -1:].expand(-1, T_OUT, -1)], 1))
        decoded = model.reconstruct(model.decode(model.destandardise_latents(out)))
        expected = history[:, -1:] + decoded[:, T_IN:] - decoded[:, T_IN - 1 : T_IN]
        torch.testing.assert_close(model(history), expected, rtol=1e-5, atol=1e-3)
        # the same weights in the paper's class decode the outputs themselves
        plain = SpecTrHuMS(T_IN, T_OUT, V, BASIS, **SMALL)
        plain.load_state_dict(model.state_dict())
        torch.testing.assert_close(plain.eval()(history), decoded[:, T_IN:], rtol=1e-5, atol=1e-3)


def test_a_transformer_that_repeats_itself_predicts_repeat_last_exactly():
    model = anchored()
    with torch.no_grad():  # one output whatever the position: no change predicted
        for p in model.transformer.out.parameters():
            p.zero_()
    history = motion(2)[:, :T_IN]
    with torch.no_grad():
        torch.testing.assert_close(
            model(history), history[:, -1:].expand(-1, T_OUT, -1, -1), rtol=0, atol=1e-3
        )


def test_rollout_anchors_each_chunk_on_the_frame_before_it():
    model = anchored().double()
    history = motion(2, frames=T_IN + 2).double()
    with torch.no_grad():
        first = model(history[:, -T_IN:])
        long = model.rollout(history, T_OUT + 2)
        torch.testing.assert_close(long[:, :T_OUT], first)
        second = model(torch.cat([history, first], 1)[:, -T_IN:])
        torch.testing.assert_close(long[:, T_OUT:], second[:, :2])


def test_completion_is_refused():
    with pytest.raises(SpecTrHuMSError, match="task 'completion' is not prediction"):
        AnchoredSpecTrHuMS(T_IN, T_OUT, V, BASIS, task="completion", **SMALL)


def test_the_registry_entry_runs_the_paper_entrys_weights(tmp_path):
    entry = load_registry().get("spectrhums_anchored")
    assert entry.weights_of == "spectrhums" and not entry.trainable
    assert entry.hparams == load_registry().get("spectrhums").hparams
    bad = tmp_path / "registry.yaml"
    for field, message in (
        ("weights_of: other\n    trainable: true", "trained as that one"),
        ("weights_of: m", "names another model"),
        ("weights_of: [a]", "field 'weights_of': input should be a valid string"),
    ):
        bad.write_text(
            "models:\n  m:\n    class: zoo.models.repeat_last.RepeatLast\n"
            f"    representation: joints\n    {field}\n"
        )
        with pytest.raises(RegistryError, match=message):
            Registry.from_files(bad)


def test_the_residual_transformer_starts_as_repeat_last_and_shares_the_papers_initialisation():
    from zoo.models.spectrhums_residual import ResidualSpecTrHuMS

    torch.manual_seed(0)
    residual = trained_stats(ResidualSpecTrHuMS(T_IN, T_OUT, V, BASIS, **SMALL)).eval()
    torch.manual_seed(0)
    paper = trained_stats(SpecTrHuMS(T_IN, T_OUT, V, BASIS, **SMALL)).eval()
    ours = {
        k.replace("transformer.inner.", "transformer."): v for k, v in residual.state_dict().items()
    }
    differ = {k for k, v in paper.state_dict().items() if not torch.equal(v, ours[k])}
    assert differ == {"transformer.out.weight"}  # the paper's biases start at zero too
    assert not ours["transformer.out.weight"].any()
    history = motion(2)[:, :T_IN]
    with torch.no_grad():
        z = residual.standardise_latents(residual.encode(residual.project(history)))
        window = residual.fill_window(z)
        torch.testing.assert_close(
            residual.transformer(window), window
        )  # observed kept, last repeated
        expected = residual.reconstruct(residual.decode(residual.destandardise_latents(z[:, -1:])))
        torch.testing.assert_close(
            residual(history), expected.expand(-1, T_OUT, -1, -1), rtol=1e-5, atol=1e-3
        )
    # the paper's recipe, validated on whole held-out recordings (issue 29's split)
    entry, paper = load_registry().get("spectrhums_residual"), load_registry().get("spectrhums")
    assert entry.trainable and entry.train == {
        **paper.train,
        "val_split": "recordings",
        "val_fraction": 0.125,
    }


def test_the_residual_model_anchored_is_both_changes():
    from zoo.models.spectrhums_residual import AnchoredResidualSpecTrHuMS, ResidualTransformer

    torch.manual_seed(0)
    model = trained_stats(AnchoredResidualSpecTrHuMS(T_IN, T_OUT, V, BASIS, **SMALL)).eval()
    assert isinstance(model.transformer, ResidualTransformer)
    history = motion(2)[:, :T_IN]
    with torch.no_grad():  # untrained: no change from the last observed frame
        torch.testing.assert_close(
            model(history), history[:, -1:].expand(-1, T_OUT, -1, -1), rtol=0, atol=1e-3
        )
    assert load_registry().get("spectrhums_residual_anchored").weights_of == "spectrhums_residual"


def test_anchored_rows_carry_no_autoencoder_floor_of_the_papers_inference():
    # the evaluator scores a floor only where the model has one: the paper's floor is not the
    # anchored model's
    assert AnchoredSpecTrHuMS.autoencoder_floor is None
    assert callable(SpecTrHuMS.autoencoder_floor)


def test_weights_of_must_name_a_trainable_model_that_sees_the_same_data(tmp_path):
    base = (
        "models:\n  trained:\n    class: zoo.models.repeat_last.RepeatLast\n"
        "    representation: mesh\n    trainable: true\n"
        "  plain:\n    class: zoo.models.repeat_last.RepeatLast\n    representation: mesh\n"
    )
    bad = tmp_path / "registry.yaml"
    for target, extra, message in (
        ("nowhere", "", "'nowhere' is not a registered model"),
        ("plain", "", "'plain' is not trainable"),
        ("trained", "    context: [basis]\n", "its context \\('basis',\\) differs"),
        ("trained", "    task: completion\n", "its task 'completion' differs"),
    ):
        bad.write_text(
            base + "  variant:\n    class: zoo.models.repeat_last.RepeatLast\n"
            f"    representation: mesh\n    weights_of: {target}\n{extra}"
        )
        with pytest.raises(RegistryError, match=f"'variant': field 'weights_of': {message}"):
            Registry.from_files(bad)


def test_pretrained_and_the_default_label_of_a_weights_of_entry(tmp_path, capsys):
    import zoo
    from zoo.hub.model_source import ModelSource
    from zoo.protocol.benchmark import get_benchmark

    registry = load_registry()
    weights = "weights/cmu_anny_oi_low/spectrhums@last.safetensors"
    source = ModelSource.of(model="spectrhums_anchored", weights=weights)
    assert source.default_label("spectrhums_anchored") == "spectrhums_anchored@last"
    assert ModelSource.of(weights=weights).default_label("spectrhums") == "spectrhums@last"
    model = zoo.create_model(
        "spectrhums_anchored@last", benchmark="cmu_anny_oi_low", pretrained=True
    )
    assert type(model) is AnchoredSpecTrHuMS and not model.training
    untrained = ModelSource.of("spectrhums_anchored").load(
        registry, get_benchmark("cmu_anny_oi_low")
    )
    untrained.warn_if_untrained()
    assert (
        "spectrhums_anchored is spectrhums's weights and no --checkpoint" in capsys.readouterr().err
    )


def test_every_weights_of_row_ships_its_link_to_the_weights_it_runs():
    import os

    from zoo.hub.model_source import ModelSource
    from zoo.paths import REPO_ROOT
    from zoo.protocol.benchmark import get_benchmark

    registry = load_registry()
    runs = {n: e.weights_of for n, e in registry.entries.items() if e.weights_of}
    rows = [
        p
        for p in (REPO_ROOT / "results").glob("*/*/*")
        if p.is_dir() and p.name.partition("@")[0] in runs
    ]
    assert rows, "no committed row of a weights_of entry"
    for row in rows:
        bench, label = row.parent.parent.name, row.name
        name, at, suffix = label.partition("@")
        link = REPO_ROOT / "weights" / bench / f"{label}.safetensors"
        target = REPO_ROOT / "weights" / bench / f"{runs[name]}{at}{suffix}.safetensors"
        assert link.is_file(), f"{row}: no {link}"
        assert os.path.realpath(link) == os.path.realpath(target), f"{link} is not {target}"
    # the link scores as the entry it names, never as the model its file holds
    link = REPO_ROOT / "weights" / "cmu_anny_oi_low" / "spectrhums_anchored@last.safetensors"
    loaded = ModelSource.of(weights=link).load(registry, get_benchmark("cmu_anny_oi_low"))
    assert type(loaded.model) is AnchoredSpecTrHuMS
    assert loaded.label == "spectrhums_anchored@last"
