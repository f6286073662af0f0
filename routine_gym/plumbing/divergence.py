"""Stop a training run whose numbers stop being numbers, with one line instead of a result.

A loss that overflows (`--reward-scale 1e30`: returns of 1e30 square to `inf`) or a step that
throws the weights out of range (`--learning-rate 1e30`) leaves a run that still "trains" on
`inf`/`nan` and evaluates a broken policy, or one that dies with a traceback in the middle of a
rollout. Every script in `algos/` checks instead, at three places:

- each update, before the optimizer's step: `check_update(step, loss, grad_norm)`, a read of
  the loss and of the gradient norm `clip_grad_norm_` returns anyway (about 1.5 us an update
  on this CPU, under 0.3 % of a MinAtar A2C update), so a non-finite update is never applied;
- before a checkpoint is written and before the final evaluation (`routine_gym.plumbing.run`):
  `check_parameters`, every floating tensor of the models and optimizers, so a checkpoint
  never holds a broken state and the last good one stays on disk;
- around the whole run (`run_script`): torch's refusal to sample from non-finite action
  probabilities (weights still finite but so large that the policy's logits overflow, the first
  sign of `--learning-rate 1e30`) becomes the same report (`as_divergence`).

Each raises `TrainingDiverged`, which `run_script` prints as one line on stderr naming what went
non-finite and the step, and the script exits with code 3 (`EXIT_CODE`): the command was
valid, the run diverged. 2 stays the code of a user's mistake and 1 that of any other failure (a
bug's traceback, a full disk), so a sweep can tell a divergence, an answer about the settings
(a tuning grid's point that diverges loses, `routine_gym.experiments.derived`), from a fault.
No `eval.json` is written; the run folder (its TensorBoard curves up to the failure) and its
last checkpoint stay as they were.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

import torch

from routine_gym.errors import DIVERGED_EXIT

__all__ = ["EXIT_CODE", "TrainingDiverged", "as_divergence", "check_parameters", "check_update"]

#: The exit code of a run stopped by `TrainingDiverged` (1: any other failure, 2: a user's
#: mistake).
EXIT_CODE = DIVERGED_EXIT

#: What a run can do about it, said once in every report.
_ADVICE = "the last checkpoint, if any, is intact; a lower learning rate or reward scale may help"


class TrainingDiverged(RuntimeError):
    """A loss, a gradient or a parameter of a training run became `inf` or `nan`."""

    def __init__(self, what: str, step: int | None = None, unit: str = "step") -> None:
        where = "" if step is None else f" at {unit} {step:,}"
        super().__init__(f"training stopped{where}: {what} ({_ADVICE})")
        self.what, self.step = what, step


def _value(x: Any) -> float:
    return x.item() if isinstance(x, torch.Tensor) else float(x)


def check_update(step: int, loss: torch.Tensor, grad_norm: torch.Tensor | float | None = None,
                 *, parts: Mapping[str, Any] | None = None, unit: str = "step") -> None:
    """Raise `TrainingDiverged` when the update's loss or gradient norm is not finite.

    Call it after `loss.backward()` (and the gradient clipping, whose returned total norm is
    `grad_norm`) and before `optimizer.step()`: one scalar read when all is well; the loss's
    `parts` (`{"value loss": v_loss, ...}`) are looked at only to name the culprit.

    Args:
        step: the step counter the message names.
        loss: the scalar loss of the update.
        grad_norm: the total gradient norm (None: the loss alone is checked).
        parts: the terms of the loss, by name, to say which went non-finite.
        unit: what `step` counts (`"step"`, `"CompILE step"`, ...).

    Example:
        >>> check_update(10, torch.tensor(0.5), torch.tensor(3.0))
        >>> try:
        ...     check_update(12, torch.tensor(float("inf")), parts={"value loss": float("inf")})
        ... except TrainingDiverged as exc:
        ...     print(exc.what, "at step", exc.step)
        the value loss is inf at step 12
    """
    # Two scalar reads (0.9 us in all on this CPU); an added tensor would cost 4x that.
    if math.isfinite(_value(loss)) and (grad_norm is None or math.isfinite(_value(grad_norm))):
        return
    for name, value in (parts or {}).items():
        number = _value(value)
        if not math.isfinite(number):
            raise TrainingDiverged(f"the {name} is {number}", step, unit)
    number = _value(loss)
    if not math.isfinite(number):
        raise TrainingDiverged(f"the loss is {number}", step, unit)
    raise TrainingDiverged(f"the gradient norm is {_value(grad_norm)}", step, unit)


def check_parameters(step: int | None, state: Mapping[str, Any], unit: str = "step") -> None:
    """Raise `TrainingDiverged` when a floating tensor of `state` is not finite.

    Args:
        step: the step counter the message names (None: no step).
        state: objects with a `state_dict` (models, optimizers) or tensors, by name.
        unit: what `step` counts.
    """
    for name, target in state.items():
        for key, tensor in _tensors(target.state_dict() if hasattr(target, "state_dict")
                                    else target):
            if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
                where = f"{name}'s {key}" if key else name
                raise TrainingDiverged(f"{where} holds a non-finite number", step, unit)


def _tensors(value: Any, key: str = "") -> Iterable[tuple[str, torch.Tensor]]:
    """The tensors of a (nested) state dict, with their dotted keys."""
    if isinstance(value, torch.Tensor):
        yield key, value
    elif isinstance(value, Mapping):
        for k, v in value.items():
            yield from _tensors(v, f"{key}.{k}" if key else str(k))
    elif isinstance(value, list | tuple):
        for i, v in enumerate(value):
            yield from _tensors(v, f"{key}.{i}" if key else str(i))


#: The message of torch's `multinomial` for probabilities that are not numbers (the policy's
#: logits overflowed); the sampling of every script ends there.
_NON_FINITE_PROBABILITIES = "probability tensor contains either `inf`, `nan` or element < 0"


def as_divergence(exc: BaseException, step: int | None) -> TrainingDiverged | None:
    """`TrainingDiverged` for torch's refusal to sample non-finite action probabilities (the
    policy's outputs overflowed), else None."""
    if isinstance(exc, RuntimeError) and _NON_FINITE_PROBABILITIES in str(exc):
        return TrainingDiverged("the policy's action probabilities are not finite (its "
                                "outputs overflowed)", step, "the rollout after step")
    return None
