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


# -- the compiled loops (routine_gym/_native/_masked_gru.cpp) against the torch loop --------------

import contextlib  # noqa: E402

import pytest  # noqa: E402

import routine_gym.baselines.compile.masked_gru as masked_gru_module  # noqa: E402
from routine_gym import _native  # noqa: E402

core = _native.core("masked_gru")
# Not built, or ROUTINE_GYM_NATIVE turns it off: the torch loop's tests above still run.
needs_core = pytest.mark.skipif(core is None,
                                reason=f"masked_gru: {_native.unavailable('masked_gru')}")

BUILDS = ["best", "portable"]


@contextlib.contextmanager
def _build(name: str):
    core.select(name)
    try:
        yield
    finally:
        core.select("best")


@contextlib.contextmanager
def _threads(count: int):
    before = torch.get_num_threads()
    torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _inputs(b: int, t: int, h: int, dtype: torch.dtype, seed: int, scale: float = 1.0):
    generator = torch.Generator().manual_seed(seed)
    gates = (scale * torch.randn(b, t, 3 * h, generator=generator, dtype=dtype)).requires_grad_()
    mask = torch.rand(b, t, generator=generator, dtype=dtype)
    mask[:, 0] = 1.0
    if t > 2:
        mask[0, 2] = 0.0  # an exact restart, as after a hard boundary
    mask.requires_grad_()
    weight = (torch.randn(3 * h, h, generator=generator, dtype=dtype) / h ** 0.5).requires_grad_()
    bias = torch.randn(3 * h, generator=generator, dtype=dtype).requires_grad_()
    upstream = torch.randn(b, t, h, generator=generator, dtype=dtype)
    return (gates, mask, weight, bias), upstream


def _run(function, inputs, upstream):
    for x in inputs:
        x.grad = None
    out = function.apply(*inputs)
    (out * upstream).sum().backward()
    return [out.detach().clone(), *(x.grad.clone() for x in inputs)]


@needs_core
@pytest.mark.parametrize("build", BUILDS)
@pytest.mark.parametrize(("b", "t", "h"), [(16, 33, 128), (1, 1, 1), (5, 7, 3), (7, 4, 20),
                                           (3, 9, 17)])
def test_compiled_loops_equal_the_torch_loop_in_float64(build, b, t, h):
    """Every shape's remainder path (rows not a multiple of the 4-row tile, columns not a multiple
    of the 2-vector tile) gives the torch loop's outputs and gradients to float64 rounding."""
    inputs, upstream = _inputs(b, t, h, torch.float64, seed=b * 100 + h)
    with _build(build):
        compiled = _run(masked_gru_module._CompiledMaskedGRU, inputs, upstream)
    reference = _run(masked_gru_module._TorchMaskedGRU, inputs, upstream)
    for name, got, expected in zip(["out", "gates", "mask", "weight", "bias"], compiled, reference,
                                   strict=True):
        torch.testing.assert_close(got, expected, rtol=1e-12, atol=1e-13, msg=name)


@needs_core
@pytest.mark.parametrize("build", BUILDS)
@pytest.mark.parametrize("scale", [1.0, 30.0])
def test_compiled_loops_equal_the_torch_loop_in_float32(build, scale):
    """float32 with the vectorized σ and tanh, inputs small and saturating (±100 and beyond)."""
    inputs, upstream = _inputs(16, 33, 128, torch.float32, seed=int(scale), scale=scale)
    with _build(build):
        compiled = _run(masked_gru_module._CompiledMaskedGRU, inputs, upstream)
    reference = _run(masked_gru_module._TorchMaskedGRU, inputs, upstream)
    for name, got, expected in zip(["out", "gates", "mask", "weight", "bias"], compiled, reference,
                                   strict=True):
        assert torch.isfinite(got).all(), name
        torch.testing.assert_close(got, expected, rtol=2e-5, atol=2e-5, msg=name)


@needs_core
def test_sigmoid_and_tanh_of_the_float32_loop_are_within_a_few_ulp():
    """One step from h = 0 with W_hh = 0 and b_hh = 0: r, z = σ(gi), n = tanh(gi_n), over a
    sweep of gate values from −100 to 100 (both branches of tanh, the clamp of exp)."""
    h = 1000
    values = torch.cat([torch.linspace(-100, 100, h - 8), torch.tensor(
        [0.0, -0.0, 0.625, -0.625, 0.6249, 1e-8, -1e-30, 88.5])])
    gates = values.repeat(3).view(1, 1, 3 * h)
    hs, rz, n, ghn = (torch.empty(1, 2, h), torch.empty(1, 1, 2 * h), torch.empty(1, 1, h),
                      torch.empty(1, 1, h))
    for build in BUILDS:
        with _build(build):
            core.forward(*(x.numpy() for x in (gates, torch.ones(1, 1), torch.zeros(h, 3 * h),
                                               torch.zeros(3 * h), hs, rz, n, ghn)),
                         1, 1, h, 1, False)
        exact_sigmoid = torch.sigmoid(values.double())
        exact_tanh = torch.tanh(values.double())
        torch.testing.assert_close(rz[0, 0, :h].double(), exact_sigmoid, rtol=4e-7, atol=1e-38)
        torch.testing.assert_close(n[0, 0].double(), exact_tanh, rtol=4e-7, atol=1e-38)
        assert n[0, 0, -2].item() == values[-2].item()  # tanh(x) = x for tiny x, sign kept
        assert rz[0, 0, h - 1].item() == 1.0  # σ(88.5)


@needs_core
@pytest.mark.parametrize("build", BUILDS)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_a_rows_numbers_do_not_depend_on_the_thread_count(build, dtype):
    """Each row's recurrence is one thread's: outputs and the loops' gradients are bit-identical
    at 1, 2 and 3 threads (W_hh's gradient is torch's product, compared to rounding)."""
    inputs, upstream = _inputs(16, 33, 128, dtype, seed=5)
    results = []
    for count in (1, 2, 3):
        with _threads(count), _build(build):
            results.append(_run(masked_gru_module._CompiledMaskedGRU, inputs, upstream))
    for other in results[1:]:
        for index in (0, 1, 2):  # outputs, the gates' and the mask's gradients
            assert torch.equal(other[index], results[0][index])
        torch.testing.assert_close(other[3], results[0][3], rtol=1e-5, atol=1e-5)


@needs_core
@pytest.mark.parametrize("build", BUILDS)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_nan_and_infinite_gates_come_out_as_in_the_torch_loop(build, dtype):
    """A NaN stays NaN (a diverging fit shows in its loss); ±inf gates saturate σ and tanh."""
    (gates, mask, weight, bias), upstream = _inputs(4, 5, 6, dtype, seed=11)
    with torch.no_grad():
        gates[0, 1, 2 * 6 + 3] = float("nan")  # a candidate gate of row 0, step 1
        gates[1, 0, 0] = float("inf")  # r of row 1
        gates[2, 2, 6 + 1] = -float("inf")  # z of row 2
        gates[3, 3, 2 * 6] = float("inf")  # n of row 3
    for nan_weight in (False, True):
        w = weight.detach().clone()
        if nan_weight:
            w[2 * 6 + 1, 4] = float("nan")
        inputs = [x.detach().clone().requires_grad_() for x in (gates, mask, w, bias)]
        with _build(build):
            compiled = _run(masked_gru_module._CompiledMaskedGRU, inputs, upstream)
        reference = _run(masked_gru_module._TorchMaskedGRU, inputs, upstream)
        assert torch.isnan(compiled[0]).any()
        for got, expected in zip(compiled, reference, strict=True):
            assert torch.equal(torch.isnan(got), torch.isnan(expected))
            finite = ~torch.isnan(expected)
            torch.testing.assert_close(got[finite], expected[finite], rtol=1e-5, atol=1e-5)


@needs_core
def test_double_backward_is_refused_not_silently_wrong():
    inputs, upstream = _inputs(2, 3, 4, torch.float64, seed=2)
    for function in (masked_gru_module._CompiledMaskedGRU, masked_gru_module._TorchMaskedGRU):
        out = function.apply(*inputs)
        with pytest.raises(RuntimeError, match="^masked_gru has no double backward"):
            torch.autograd.grad((out * upstream).sum(), inputs[0], create_graph=True)


def test_an_empty_batch_gives_an_empty_output():
    for shape in ((0, 3, 12), (2, 0, 12)):
        gates = torch.zeros(shape, requires_grad=True)
        out = masked_gru(gates, torch.ones(shape[:2]), torch.zeros(12, 4), torch.zeros(12))
        assert out.shape == (*shape[:2], 4)
        out.sum().backward()
        assert gates.grad.shape == shape


def test_parameters_without_gradients_get_none():
    (gates, mask, weight, bias), upstream = _inputs(3, 4, 5, torch.float32, seed=4)
    weight, bias = weight.detach(), bias.detach()
    out = masked_gru(gates, mask, weight, bias)
    (out * upstream).sum().backward()
    assert gates.grad is not None and mask.grad is not None
    assert weight.grad is None and bias.grad is None


def test_the_torch_loop_where_the_core_is_off(monkeypatch):
    inputs, upstream = _inputs(3, 4, 5, torch.float64, seed=6)
    reference = _run(masked_gru_module._TorchMaskedGRU, inputs, upstream)
    monkeypatch.setenv("ROUTINE_GYM_NATIVE", "sequitur")  # every core but this one
    out = masked_gru(*inputs)
    assert out.grad_fn.name().startswith("_TorchMaskedGRU")
    torch.testing.assert_close(out.detach(), reference[0], rtol=0, atol=0)
    monkeypatch.setenv("ROUTINE_GYM_COMPILE_GRU", "compiled")
    with pytest.raises(ValueError, match="^ROUTINE_GYM_COMPILE_GRU=compiled: the compiled core "
                                         "'masked_gru' is not there"):
        masked_gru(*inputs)
    monkeypatch.setenv("ROUTINE_GYM_COMPILE_GRU", "")  # empty: the default, the torch loop here
    assert masked_gru(*inputs).grad_fn.name().startswith("_TorchMaskedGRU")


@needs_core
def test_gcc_builds_on_an_avx2_cpu_run_the_avx2_loops():
    """The `#pragma GCC target` build and the CPU check: where both hold, the AVX2 loops run."""
    import platform
    import sysconfig
    from pathlib import Path

    cpuinfo = Path("/proc/cpuinfo")
    flags = cpuinfo.read_text().split() if cpuinfo.exists() else []
    compiler = str(sysconfig.get_config_var("CC") or "")
    if platform.machine() != "x86_64" or "gcc" not in compiler or not {"avx2", "fma"} <= set(
            flags):
        pytest.skip("not an x86-64 CPU with AVX2 and FMA under GCC")
    assert core.simd() == "avx2"
    with _build("portable"):
        assert core.simd() == "portable"
    assert core.simd() == "avx2"


@needs_core
def test_masked_gru_takes_the_compiled_loops_on_cpu_and_non_contiguous_inputs():
    inputs, upstream = _inputs(4, 6, 8, torch.float64, seed=9)
    gates, mask, weight, bias = inputs
    # The same values laid out transposed in memory.
    gates_t = gates.detach().transpose(0, 1).contiguous().transpose(0, 1).requires_grad_()
    mask_t = mask.detach().t().contiguous().t().requires_grad_()
    assert not gates_t.is_contiguous() and not mask_t.is_contiguous()
    out = masked_gru(gates_t, mask_t, weight, bias)
    assert out.grad_fn.name().startswith("_CompiledMaskedGRU")
    (out * upstream).sum().backward()
    reference = _run(masked_gru_module._TorchMaskedGRU, inputs, upstream)
    torch.testing.assert_close(out.detach(), reference[0], rtol=1e-12, atol=1e-13)
    torch.testing.assert_close(gates_t.grad, reference[1], rtol=1e-12, atol=1e-13)
    torch.testing.assert_close(mask_t.grad, reference[2], rtol=1e-12, atol=1e-13)


def test_other_dtypes_take_the_torch_loop():
    inputs, _ = _inputs(2, 3, 4, torch.float64, seed=1)
    halves = [x.detach().to(torch.bfloat16) for x in inputs]
    assert masked_gru(*halves).dtype == torch.bfloat16
    mixed = [inputs[0], inputs[1].float(), inputs[2], inputs[3]]  # mixed dtypes: torch decides
    assert not masked_gru_module._compiled(*mixed)


@needs_core
def test_the_compiled_entry_points_refuse_wrong_buffers_in_one_line():
    (gates, mask, weight, bias), _ = _inputs(2, 3, 4, torch.float32, seed=1)
    hs, rz, n, ghn = torch.empty(2, 4, 4), torch.empty(2, 3, 8), torch.empty(2, 3, 4), \
        torch.empty(2, 3, 4)
    arrays = [x.detach().numpy() for x in (gates, mask, weight.t().contiguous(), bias, hs, rz, n,
                                           ghn)]
    with pytest.raises(ValueError, match="^hs holds 96 bytes, expected 128$"):
        core.forward(*arrays[:4], torch.empty(2, 3, 4).numpy(), *arrays[5:], 2, 3, 4, 1, False)
    with pytest.raises(ValueError, match="batch, steps and hidden need to be >= 1"):
        core.forward(*arrays, 0, 3, 4, 1, False)
    with pytest.raises(ValueError, match="threads needs to be >= 1"):
        core.forward(*arrays, 2, 3, 4, 0, False)
    with pytest.raises(ValueError, match="gi holds 288 bytes, expected 576"):
        core.forward(*arrays, 2, 3, 4, 1, True)  # float32 buffers called as float64
    with pytest.raises(ValueError, match="expected 'best' or 'portable'"):
        core.select("avx512")
    core.forward(*arrays, 2, 3, 4, 1, False)
    assert core.simd() in ("avx2", "portable")


@needs_core
def test_the_environment_variable_selects_the_torch_loop(monkeypatch):
    inputs, _ = _inputs(2, 3, 4, torch.float32, seed=1)
    assert masked_gru(*inputs).grad_fn.name().startswith("_CompiledMaskedGRU")
    monkeypatch.setenv("ROUTINE_GYM_COMPILE_GRU", "torch")
    assert masked_gru(*inputs).grad_fn.name().startswith("_TorchMaskedGRU")
    monkeypatch.setenv("ROUTINE_GYM_COMPILE_GRU", "fast")
    with pytest.raises(ValueError, match="^ROUTINE_GYM_COMPILE_GRU='fast': expected 'compiled'"):
        masked_gru(*inputs)
