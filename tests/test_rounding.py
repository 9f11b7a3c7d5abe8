"""The re-runs that measure a window's rounding sensitivity (zoo.leaderboard.rounding): a float64
copy that answers in float32, and copies whose inputs move by a few units in the last place."""

import torch
from torch import nn

from zoo.leaderboard.rounding import INPUT_ULPS, in_float64, with_inputs_moved


class Sum(nn.Module):
    def forward(self, x, scale=1.0):
        return (x * scale).sum(dim=-1)


def test_a_float64_copy_computes_in_float64_and_answers_in_float32():
    torch.manual_seed(0)
    model = nn.Linear(64, 3)
    x = torch.randn(8, 64) * 1e3
    copied = in_float64(model)
    out = copied(x)
    assert out.dtype == torch.float32 and model.weight.dtype == torch.float32  # a copy
    exact = (x.double() @ model.weight.double().T + model.bias.double()).float()
    assert torch.equal(out, exact)


def test_inputs_move_by_a_few_units_in_the_last_place_the_same_way_every_run():
    x = torch.linspace(1.0, 1000.0, 4000).reshape(40, 100)
    seen = []
    for _ in range(2):
        moved = with_inputs_moved(nn.Identity(), seed=1)(x)
        ulps = (moved - x).abs() / torch.finfo(torch.float32).eps / x.abs()
        assert ulps.max() <= 2 * INPUT_ULPS and (moved != x).float().mean() > 0.5
        seen.append(moved)
    assert torch.equal(*seen)  # seeded: a check and its rerun measure the same
    assert not torch.equal(seen[0], with_inputs_moved(nn.Identity(), seed=2)(x))


def test_keyword_inputs_move_too_and_other_values_pass_untouched():
    x = torch.full((5, 7), 3.0)
    out = with_inputs_moved(Sum(), seed=3)(x, scale=2.0)
    assert out.shape == (5,) and not torch.equal(out, Sum()(x, scale=2.0))
