"""Step torch's RMSprop and Adam without importing TorchDynamo: 1.4 s off every script's start.

torch 2.13 readies its optimizers for `torch.compile` even when nothing compiles: the first
`step()` runs `import torch._dynamo` (for two `graph_break()` calls around the update, which do
nothing outside a compiled region), and the first call of `add_param_group`, `zero_grad`,
`state_dict` and `load_state_dict` imports it too, to mark them "never compile". The import
(sympy, the FX tracer) costs about 1.4 s of CPU here against 0.6 s for a whole 1,000-step smoke
run's training and evaluation (`bench/bench_script_start.py`): every script pays it once, the
test suite hundreds of times. No script of routine-gym compiles
anything, so the marks are true already and the graph breaks are no-ops.

`eager_optimizers()` gives `RMSprop` and `Adam` (and `AdamW`, which inherits it) a `step`
that is torch's own update under the same grad mode (`torch.set_grad_enabled(differentiable)`,
as torch's wrapper sets it) without the graph breaks, and torch's wrapped step itself while a
graph is being compiled; and it marks the four methods as done (`__dynamo_disable`, the
attribute torch's wrapper caches its mark in, set to the method itself: the wrapper then calls
it directly, as it does after the import outside a compiled region). The marks hold for the
whole process: a script of one's own that uses `run_script` and compiles should set the switch
below to 0, so that torch's marks keep the compiler out of those methods. The update is the same
arithmetic, so a seeded run's numbers are the same bit for bit (`tests/test_eager_optim.py`).
It does nothing when `torch._dynamo` is imported already (a caller that may compile keeps
torch's behaviour), and leaves alone any wrapper not of the shape it knows (another torch:
the import happens as before). `run_script` calls it, so it holds in the scripts' processes
only, never in a library caller's; `ROUTINE_GYM_EAGER_OPTIM=0` in the environment turns it off
(torch's own path, the peer of the benchmark).
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable
from typing import Any

__all__ = ["eager_optimizers"]

#: The environment variable that turns it off (`0`).
SWITCH = "ROUTINE_GYM_EAGER_OPTIM"

#: The methods of `torch.optim.Optimizer` that torch wraps in `_disable_dynamo`.
_METHODS = ("add_param_group", "zero_grad", "state_dict", "load_state_dict")


def _mark(wrapper: Any, torch_file: str, name: str) -> bool:
    """Mark `wrapper`'s function as never compiled, if `wrapper` is a wrapper of `torch_file`
    named `name` around it (`functools.wraps`' `__wrapped__`)."""
    fn, code = getattr(wrapper, "__wrapped__", None), getattr(wrapper, "__code__", None)
    if fn is None or code is None or code.co_name != name or code.co_filename != torch_file:
        return False
    if getattr(fn, "__dynamo_disable", None) is None:
        fn.__dynamo_disable = fn
    return True


def _eager_step(step: Callable[..., Any]) -> Callable[..., Any]:
    """Torch's `step` body under the grad mode its `_use_grad_for_differentiable` sets, without
    that wrapper's `torch._dynamo.graph_break()` calls."""
    import torch

    body = step.__wrapped__

    @functools.wraps(body)
    def eager_step(self: Any, *args: Any, **kwargs: Any) -> Any:
        if torch.compiler.is_compiling():  # a flag's read: torch's own wrapper, graph breaks
            return step(self, *args, **kwargs)
        with torch.set_grad_enabled(self.defaults["differentiable"]):
            return body(self, *args, **kwargs)

    eager_step.eager = True
    return eager_step


def eager_optimizers() -> list[str]:
    """Let `torch.optim.RMSprop` and `Adam` run without importing `torch._dynamo`; returns what
    it changed (empty when dynamo is imported already or torch's wrappers are not as expected).

    Example:
        >>> import torch
        >>> changed = eager_optimizers()
        >>> "torch._dynamo" in sys.modules or "RMSprop.step" in changed
        True
    """
    if "torch._dynamo" in sys.modules or os.environ.get(SWITCH, "1") == "0":
        return []
    import torch
    import torch._compile
    import torch.optim

    optimizer = sys.modules.get("torch.optim.optimizer")
    if optimizer is None:
        return []
    compile_file, optim_file = torch._compile.__file__, optimizer.__file__
    changed = [f"Optimizer.{name}" for name in _METHODS
               if _mark(getattr(torch.optim.Optimizer, name, None), compile_file, "inner")]
    for cls in (torch.optim.RMSprop, torch.optim.Adam):
        step = cls.__dict__.get("step")
        if getattr(step, "eager", False):
            changed.append(f"{cls.__name__}.step")
            continue
        if getattr(step, "hooked", False):  # an optimizer was built already: leave it be
            continue
        code = getattr(step, "__code__", None)
        if (code is None or code.co_name != "_use_grad" or code.co_filename != optim_file
                or not hasattr(step, "__wrapped__")):
            continue
        cls.step = _eager_step(step)
        changed.append(f"{cls.__name__}.step")
    return changed
