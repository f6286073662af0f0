"""`masked_gru` is CompILE's GRUCell loop: same outputs, same gradients (float64), gradcheck."""

from __future__ import annotations

import torch

from routine_gym.baselines.compile.masked_gru import masked_gru


def _loop(cell: torch.nn.GRUCell, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    hidden, outputs = x.new_zeros(x.shape[0], cell.hidden_size), []
    for t in range(x.shape[1]):
        hidden = cell(x[:, t], hidden) * mask[:, t, None]
        outputs.append(hidden)
    return torch.stack(outputs, dim=1)


def test_outputs_and_every_gradient_equal_the_grucell_loop():
    torch.manual_seed(0)
    cell = torch.nn.GRUCell(5, 4).double()
    x = torch.randn(3, 7, 5, dtype=torch.float64, requires_grad=True)
    # A mask like CompILE's: 1 at first, soft in the middle, exactly 0 somewhere.
    mask = torch.rand(3, 7, dtype=torch.float64)
    mask[:, 0], mask[1, 3] = 1.0, 0.0
    mask.requires_grad_(True)
    weight = torch.randn(3, 7, 4, dtype=torch.float64)  # a loss that weighs every output
    results = []
    for fused in (False, True):
        cell.zero_grad()
        x.grad = mask.grad = None
        if fused:
            gates = torch.nn.functional.linear(x, cell.weight_ih, cell.bias_ih)
            out = masked_gru(gates, mask, cell.weight_hh, cell.bias_hh)
        else:
            out = _loop(cell, x, mask)
        (out * weight).sum().backward()
        results.append([out.detach().clone(), x.grad.clone(), mask.grad.clone(),
                        *(p.grad.clone() for p in cell.parameters())])
    for loop_value, fused_value in zip(*results, strict=True):
        torch.testing.assert_close(fused_value, loop_value, rtol=1e-10, atol=1e-12)
    assert results[1][2][1, 3] != 0  # a zero mask still has a gradient (its own state's)


def test_gradcheck():
    torch.manual_seed(1)
    gates = torch.randn(2, 4, 9, dtype=torch.float64, requires_grad=True)
    mask = torch.rand(2, 4, dtype=torch.float64, requires_grad=True)
    weight_hh = torch.randn(9, 3, dtype=torch.float64, requires_grad=True)
    bias_hh = torch.randn(9, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(masked_gru, (gates, mask, weight_hh, bias_hh))


def test_float32_matches_the_loop_to_float_rounding():
    torch.manual_seed(2)
    cell = torch.nn.GRUCell(128, 128)
    x, mask = torch.randn(16, 33, 128), torch.rand(16, 33)
    gates = torch.nn.functional.linear(x, cell.weight_ih, cell.bias_ih)
    with torch.no_grad():
        torch.testing.assert_close(masked_gru(gates, mask, cell.weight_hh, cell.bias_hh),
                                   _loop(cell, x, mask), rtol=1e-5, atol=1e-6)


def test_the_elbo_decoder_pass_is_policy_logits_of_every_step_and_segment():
    from routine_gym.baselines.compile.model import CompILE, CompILEConfig

    torch.manual_seed(3)
    model = CompILE(CompILEConfig(env_id="CartPole-v1", obs_shape=(4,), obs_dtype="float32",
                                  num_actions=3, num_latents=5)).double()
    features = torch.randn(2, 6, model.encoder.num_features, dtype=torch.float64)
    latents = torch.softmax(torch.randn(4, 2, 5, dtype=torch.float64), dim=-1)  # [M, B, Z]
    expanded = model.policy_logits(features.unsqueeze(0).expand(4, -1, -1, -1),
                                   latents.unsqueeze(2).expand(-1, -1, 6, -1))
    torch.testing.assert_close(model._segment_policy_logits(features, latents), expanded,
                               rtol=1e-12, atol=1e-12)
