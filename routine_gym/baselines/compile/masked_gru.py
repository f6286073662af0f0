"""CompILE's masked GRU as one autograd function: the recurrence written out, forward and back.

The recognition model runs a GRU over each window once per segment (`CompILE.recognise`), its
state multiplied after each step by a soft mask that restarts it at the previous boundary:

    r_t = σ(gi_r,t + W_hr h_{t−1} + b_hr)     z_t = σ(gi_z,t + W_hz h_{t−1} + b_hz)
    n_t = tanh(gi_n,t + r_t ⊙ (W_hn h_{t−1} + b_hn))
    h_t = ((1 − z_t) ⊙ n_t + z_t ⊙ h_{t−1}) ⊙ m_t,        h_{−1} = 0,

where `gi_t = W_ih x_t + b_ih` (`torch.nn.GRUCell`'s gates and weight layout, r, z, n). With
`GRUCell` in a Python loop, autograd recorded a dozen small operations per step and replayed them
backward: 10 segments × 33 steps per batch made the fit take minutes on a CPU. Here:

- the input projection `gi` is one matrix product for the whole window, shared by every segment
  (the caller computes it, so its gradient flows through autograd as usual);
- the loop runs without recording, and `backward` walks it in reverse with the hand-derived
  gradients; the gradient of `W_hh` is one matrix product over all steps at the end.

Two implementations of the loops, one function:

- `_CompiledMaskedGRU` (CPU, float32 or float64, all four tensors the same dtype; what the fit
  runs): each loop is one call into the compiled core `masked_gru`
  (`routine_gym/_native/_masked_gru.cpp`, through `routine_gym._native.core`), which runs
  every step in C++ with the GIL released, the batch's rows split among `torch.get_num_threads()`
  threads, the step's product in register tiles, σ and tanh vectorized (float32: a Cephes-style
  exp, within a few units in the last place; float64: the C library's). In torch a step was a
  dozen operations of a few microseconds each on [16, 128] tensors. Each row is one thread's, so
  the outputs and the gates' and mask's gradients do not depend on the thread count.
- `_TorchMaskedGRU`: the same loops in torch operations, for other devices and dtypes, where
  the core is not built or `ROUTINE_GYM_NATIVE` turns it off, and where the environment
  variable `ROUTINE_GYM_COMPILE_GRU=torch` asks for it (to reproduce a fit made before the
  compiled loops, bit for bit).

The compiled loops round differently from torch's (their own products, σ and tanh), so a seeded
fit is not bit-identical to one made with the torch loop; it is the same model and loss.
`tests/test_masked_gru.py` checks both against the `GRUCell` loop (float64, to 1e-10) and with
`torch.autograd.gradcheck`, the compiled loops against the torch loop in float64 (to 1e-12, on
shapes that take every remainder path of the tiles) and float32 (saturating inputs included), and
both builds of the compiled loops (AVX2 and portable).
"""

from __future__ import annotations

import os

import torch

from routine_gym import _native
from routine_gym.errors import UsageError

__all__ = ["gru_choice", "masked_gru"]

#: The environment variable that picks the loops: `compiled` (the default) or `torch`.
GRU_VARIABLE = "ROUTINE_GYM_COMPILE_GRU"


def gru_choice() -> str:
    """`ROUTINE_GYM_COMPILE_GRU`: `"compiled"` (also when unset or empty) or `"torch"`.

    Raises:
        UsageError: any other value, or `compiled` asked for where the module was not built.
    """
    choice = os.environ.get(GRU_VARIABLE, "") or "compiled"
    if choice not in ("compiled", "torch"):
        raise UsageError(f"{GRU_VARIABLE}={choice!r}: expected 'compiled' (the default) or "
                         "'torch'")
    if choice == "compiled" and os.environ.get(GRU_VARIABLE) \
            and _native.core("masked_gru") is None:
        raise UsageError(f"{GRU_VARIABLE}=compiled: the compiled core 'masked_gru' is not "
                         f"there ({_native.unavailable('masked_gru')})")
    return choice


def _refuse_double_backward() -> None:
    """Both backwards compute outside autograd: under `create_graph=True` (grad mode on inside
    `backward`) their gradients would carry no graph, and a gradient penalty would lose this
    function's second-order terms without a word."""
    if torch.is_grad_enabled():
        raise RuntimeError("masked_gru has no double backward: its backward is not "
                           "differentiable (create_graph=True)")


class _TorchMaskedGRU(torch.autograd.Function):
    """The recurrence in torch operations: any device and dtype (the compiled loops' reference)."""

    # Both loops index prebuilt per-step views (`unbind`, one C call each): at 16 × 128 a view
    # made in Python costs about what the arithmetic does.

    @staticmethod
    def forward(ctx, gi: torch.Tensor, mask: torch.Tensor, weight_hh: torch.Tensor,
                bias_hh: torch.Tensor) -> torch.Tensor:
        b, steps, three_h = gi.shape
        h = three_h // 3
        gi_t = gi.transpose(0, 1)  # [T, B, 3H]
        outputs = gi.new_empty(steps + 1, b, h)  # h_{−1} = 0, then h_0 … h_{T−1}
        outputs[0] = 0
        rz = gi.new_empty(steps, b, 2 * h)  # σ of the r and z gates
        n = gi.new_empty(steps, b, h)
        gh_n = gi.new_empty(steps, b, h)  # W_hn h_{t−1} + b_hn
        weight_rz, weight_n = weight_hh[:2 * h].t(), weight_hh[2 * h:].t()
        bias_rz, bias_n = bias_hh[:2 * h], bias_hh[2 * h:]
        views = zip(outputs[:-1].unbind(0), outputs[1:].unbind(0),
                    gi_t[..., :2 * h].unbind(0), gi_t[..., 2 * h:].unbind(0),
                    mask.t().unsqueeze(-1).unbind(0), rz.unbind(0), rz[..., :h].unbind(0),
                    rz[..., h:].unbind(0), n.unbind(0), gh_n.unbind(0), strict=True)
        for hidden, out, gi_rz, gi_n, m, rz_t, r, z, n_t, gh_n_t in views:
            torch.sigmoid(torch.addmm(bias_rz, hidden, weight_rz).add_(gi_rz), out=rz_t)
            torch.addmm(bias_n, hidden, weight_n, out=gh_n_t)
            torch.tanh(torch.addcmul(gi_n, r, gh_n_t), out=n_t)
            # h_t = ((1 − z) n + z h_{t−1}) m_t = (n + z (h_{t−1} − n)) m_t
            torch.mul(torch.addcmul(n_t, z, hidden - n_t), m, out=out)
        ctx.save_for_backward(mask, weight_hh, outputs, rz, n, gh_n)
        return outputs[1:].transpose(0, 1)

    @staticmethod
    def backward(ctx, grad_outputs: torch.Tensor):
        _refuse_double_backward()
        mask, weight_hh, outputs, rz, n, gh_n = ctx.saved_tensors
        steps, b, h = n.shape
        previous = outputs[:-1]  # h_{t−1}
        r, z = rz[..., :h], rz[..., h:]
        # What does not depend on the gradient coming back, for all steps at once.
        unmasked = torch.addcmul(n, z, previous - n)
        mask_t = mask.t().unsqueeze(-1)
        to_n = (1 - z) * (1 - n * n) * mask_t  # ∂h_t/∂(n's pre-activation)
        to_z = (previous - n) * z * (1 - z) * mask_t  # ∂h_t/∂(z's pre-activation)
        to_r = gh_n * r * (1 - r)  # ∂(n's pre-activation)/∂(r's pre-activation)
        to_previous = z * mask_t  # ∂h_t/∂h_{t−1} outside the gates
        grad_outputs = grad_outputs.transpose(0, 1)
        grad_h = grad_outputs.new_empty(steps, b, h)  # ∂L/∂h_t, all paths
        grad_gh = grad_outputs.new_empty(steps, b, 3 * h)  # ∂L/∂(W_hh h_{t−1} + b_hh)
        grad_pre_n = grad_outputs.new_empty(steps, b, h)
        carried = grad_outputs.new_zeros(b, h)  # ∂L/∂h_t from the steps after t
        views = zip(grad_outputs.unbind(0), grad_h.unbind(0), grad_pre_n.unbind(0),
                    grad_gh.unbind(0), grad_gh[..., :h].unbind(0),
                    grad_gh[..., h:2 * h].unbind(0), grad_gh[..., 2 * h:].unbind(0),
                    to_n.unbind(0), to_z.unbind(0), to_r.unbind(0), r.unbind(0),
                    to_previous.unbind(0), strict=True)
        for (grad_out, grad_h_t, grad_n, grad_gh_t, grad_r_t, grad_z_t, grad_ghn_t, to_n_t,
             to_z_t, to_r_t, r_t, to_previous_t) in reversed(list(views)):
            torch.add(grad_out, carried, out=grad_h_t)
            torch.mul(grad_h_t, to_n_t, out=grad_n)
            torch.mul(grad_n, to_r_t, out=grad_r_t)
            torch.mul(grad_h_t, to_z_t, out=grad_z_t)
            torch.mul(grad_n, r_t, out=grad_ghn_t)
            carried = torch.addmm(grad_h_t * to_previous_t, grad_gh_t, weight_hh)
        grad_mask = (grad_h * unmasked).sum(dim=-1).t()
        grad_gi = torch.cat([grad_gh[..., :2 * h], grad_pre_n], dim=-1).transpose(0, 1)
        grad_weight = grad_gh.reshape(-1, 3 * h).t() @ previous.reshape(-1, h)
        grad_bias = grad_gh.sum(dim=(0, 1))
        return grad_gi, grad_mask, grad_weight, grad_bias


class _CompiledMaskedGRU(torch.autograd.Function):
    """The recurrence in the compiled core `masked_gru` (contiguous float32/float64 CPU
    tensors; `_compiled` has checked that the core is there)."""

    @staticmethod
    def forward(ctx, gi: torch.Tensor, mask: torch.Tensor, weight_hh: torch.Tensor,
                bias_hh: torch.Tensor) -> torch.Tensor:
        b, steps, three_h = gi.shape
        h = three_h // 3
        gi, mask = gi.contiguous(), mask.contiguous()
        weight, bias = weight_hh.detach().contiguous(), bias_hh.detach().contiguous()
        weight_t = weight.t().contiguous()  # [H, 3H]: the rows of each step's product
        hs = gi.new_empty(b, steps + 1, h)  # h_{−1} = 0, then h_0 … h_{T−1}
        rz, n, gh_n = gi.new_empty(b, steps, 2 * h), gi.new_empty(b, steps, h), \
            gi.new_empty(b, steps, h)
        _native.core("masked_gru").forward(
            *_arrays(gi, mask, weight_t, bias, hs, rz, n, gh_n), b, steps, h,
            torch.get_num_threads(), gi.dtype == torch.float64)
        ctx.save_for_backward(mask, weight, hs, rz, n, gh_n)
        return hs[:, 1:]

    @staticmethod
    def backward(ctx, grad_outputs: torch.Tensor):
        _refuse_double_backward()
        mask, weight, hs, rz, n, gh_n = ctx.saved_tensors
        b, steps, h = n.shape
        grad_outputs = grad_outputs.contiguous()
        grad_gh = n.new_empty(b, steps, 3 * h)  # ∂L/∂(W_hh h_{t−1} + b_hh)
        grad_gi = n.new_empty(b, steps, 3 * h)
        grad_mask = n.new_empty(b, steps)
        _native.core("masked_gru").backward(
            *_arrays(grad_outputs, mask, weight, hs, rz, n, gh_n, grad_gh, grad_gi, grad_mask),
            b, steps, h, torch.get_num_threads(), n.dtype == torch.float64)
        flat = grad_gh.view(-1, 3 * h)
        grad_weight = flat.t() @ hs[:, :-1].reshape(-1, h) if ctx.needs_input_grad[2] else None
        grad_bias = flat.sum(dim=0) if ctx.needs_input_grad[3] else None
        return grad_gi, grad_mask, grad_weight, grad_bias


def _arrays(*tensors: torch.Tensor) -> list:
    """numpy views of CPU tensors (the buffers the compiled loops read and write)."""
    return [t.detach().numpy() for t in tensors]


def _compiled(*tensors: torch.Tensor) -> bool:
    """Whether `masked_gru` runs the compiled loops on these tensors."""
    if gru_choice() == "torch" or tensors[0].numel() == 0 or _native.core("masked_gru") is None:
        return False  # (an empty batch: nothing to loop over)
    return all(
        t.device.type == "cpu" and t.dtype == tensors[0].dtype for t in tensors
    ) and tensors[0].dtype in (torch.float32, torch.float64)


def masked_gru(gi: torch.Tensor, mask: torch.Tensor, weight_hh: torch.Tensor,
               bias_hh: torch.Tensor) -> torch.Tensor:
    """The masked GRU of the module docstring over `[B, T, 3H]` input gates.

    Args:
        gi: `W_ih x_t + b_ih` for every step, `[B, T, 3H]` (gates r, z, n, as `GRUCell`).
        mask: `[B, T]` the factor of the state after each step.
        weight_hh, bias_hh: `GRUCell`'s `weight_hh` `[3H, H]` and `bias_hh` `[3H]`.

    Returns:
        `[B, T, H]` the masked state after each step.

    Example:
        >>> import torch
        >>> cell = torch.nn.GRUCell(3, 2)
        >>> x, mask = torch.randn(4, 5, 3), torch.rand(4, 5)
        >>> gi = torch.nn.functional.linear(x, cell.weight_ih, cell.bias_ih)
        >>> out = masked_gru(gi, mask, cell.weight_hh, cell.bias_hh)
        >>> hidden, loop = torch.zeros(4, 2), []
        >>> for t in range(5):
        ...     hidden = cell(x[:, t], hidden) * mask[:, t, None]
        ...     loop.append(hidden)
        >>> torch.allclose(out, torch.stack(loop, dim=1), atol=1e-6)
        True
    """
    if _compiled(gi, mask, weight_hh, bias_hh):
        return _CompiledMaskedGRU.apply(gi, mask, weight_hh, bias_hh)
    return _TorchMaskedGRU.apply(gi, mask, weight_hh, bias_hh)
