"""Interrupting a routine: stop it at an inner state where the policy prefers another action.

A routine runs its primitive actions one inner step each (`routine_gym.wrapper`). With a stop
rule set on the env (`set_stop_rule`), before each inner step j ≥ 1 the executor shows the rule
the state the routine reached and the primitive it would take next; where the rule says stop,
the routine ends there, with executed length ℓ = j, exactly as when an episode ends inside it
(the same `routine_*` info, padded the same way, plus ``routine_interrupted``), and the agent
decides again at that state. Step 0 is never asked: the decision itself chose it.

The rule of `--interrupt MARGIN` (`policy_stop_rule`) asks the acting policy:

    interrupt  ⇔  max_a log π(a|s) − log π(next|s) > margin
               ⇔  max_a z(a|s) − z(next|s) > margin

with `z` the policy's logits over the `|A| + K` actions, `next` the routine's next primitive
and the margin in nats (`should_interrupt`). This is AG-RL's "abandon ship" (Christodoulou et
al. 2019, `AG_DDQN_Wrapper.abandon_ship`) written for a policy instead of Q-values: there a
macro is abandoned when `1 − exp(Q(next) − Q(best)) ≥` a threshold set from the running mean and
standard deviation of that disadvantage, the best being a primitive, which is then executed
inside the macro; here the margin is fixed (a flag, in the same units as the logits), the best
action ranges over everything the agent could choose (routines included), and the agent's next
decision is an ordinary one, sampled at the state the routine stopped in.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["PolicyStopRule", "StopRule", "interrupt_routines", "policy_stop_rule", "set_stop_rule",
           "should_interrupt"]

#: A stop rule: (observations [k, ...] of k envs inside a routine, their routines' next
#: primitive actions [k]) -> a bool mask [k], True where the routine stops before that action.
StopRule = Callable[[np.ndarray, np.ndarray], np.ndarray]


def should_interrupt(logits: Any, next_actions: Any, margin: float) -> np.ndarray:
    """Whether each env's routine stops before its next primitive: the policy's best action
    beats that primitive by more than `margin` nats.

        stop_i = max_a z_i(a) − z_i(next_i) > margin

    with `z_i` the logits of env i's policy over the `|A| + K` actions at the inner state its
    routine reached. It is the same test on log-probabilities, since
    log π(a) = z(a) − log Σ_b exp z(b) subtracts the same normaliser from every action:
    log π(a*) − log π(next) = z(a*) − z(next), i.e. π(a*) / π(next) > exp(margin). The logits
    are used because they need no log-sum-exp (one less pass, no rounding of its own). The
    inequality is strict, so the routine goes on where its next primitive is itself a best
    action (a tie), whatever the margin.

    Args:
        logits: [k, |A| + K] logits (numpy, or anything `np.asarray` takes: a CPU tensor).
        next_actions: [k] the routines' next primitive actions, indices in `[0, |A|)`.
        margin: the margin in nats, ≥ 0.

    Returns:
        A bool array [k].

    Example:
        >>> z = np.array([[2.0, 0.5, 0.0, 1.0],   # best: 0 (2.0); next 1: 1.5 nats behind
        ...               [2.0, 0.5, 0.0, 1.0],   # next 0 is the best: never stops
        ...               [0.0, 0.0, 0.0, 3.0]])  # a routine (3.0) beats next 2 by 3 nats
        >>> should_interrupt(z, np.array([1, 0, 2]), margin=1.0).tolist()
        [True, False, True]
        >>> should_interrupt(z, np.array([1, 0, 2]), margin=2.0).tolist()
        [False, False, True]
    """
    if not margin >= 0:
        raise ValueError(f"margin needs to be ≥ 0, actual value: {margin}")
    z = np.asarray(logits)
    chosen = np.asarray(next_actions, dtype=np.int64)
    gap = z.max(axis=-1) - np.take_along_axis(z, chosen[:, None], axis=-1)[:, 0]
    return gap > margin


class PolicyStopRule:
    """`--interrupt MARGIN`'s stop rule: `should_interrupt` on the policy's logits, one batched
    forward pass (no gradient) over the inner states of all envs asked at once.

    Args:
        logits: the policy's logits of a batch of observations (a tensor function).
        margin: the margin in nats, ≥ 0.
        device: where the observations go.

    Attributes:
        interruptions: how many routines this rule has stopped so far.
        asked: how many inner states it was asked about.
    """

    def __init__(self, logits: Callable[[Any], Any], margin: float, device: Any) -> None:
        if not margin >= 0:
            raise ValueError(f"margin needs to be ≥ 0, actual value: {margin}")
        self.logits, self.margin, self.device = logits, float(margin), device
        self.interruptions = 0
        self.asked = 0

    def __call__(self, observations: np.ndarray, next_actions: np.ndarray) -> np.ndarray:
        import torch

        with torch.inference_mode():
            z = self.logits(torch.as_tensor(observations, device=self.device)).cpu().numpy()
        stop = should_interrupt(z, next_actions, self.margin)
        self.interruptions += int(stop.sum())
        self.asked += len(stop)
        return stop

    def state_dict(self) -> dict[str, int]:
        """The counts, for a run's checkpoint: a resumed run counts on from them."""
        return {"interruptions": self.interruptions, "asked": self.asked}

    def load_state_dict(self, state: dict[str, int]) -> None:
        self.interruptions, self.asked = int(state["interruptions"]), int(state["asked"])


def set_stop_rule(envs: Any, rule: StopRule | None) -> None:
    """Give a training vector env's routines the stop rule `rule` (None: run them in full).

    A vector env of its own (`MinAtarVectorEnv`) asks the rule once per inner step for all the
    envs still inside a routine; a `SyncVectorEnv` of `RoutineActionWrapper`s (video capture,
    other families) asks it per env.

    Raises:
        ValueError: the vector env cannot ask a rule in this process (`AsyncVectorEnv`: the
            routines run in subprocesses; a batched vector env without a stop rule).
    """
    import gymnasium as gym

    if hasattr(envs, "set_stop_rule"):
        envs.set_stop_rule(rule)
        return
    # Each env's outermost wrapper: `RoutineActionWrapper` (`make_env`), which has one.
    if isinstance(envs, gym.vector.SyncVectorEnv) and all(
            hasattr(env, "set_stop_rule") for env in envs.envs):
        for env in envs.envs:
            env.set_stop_rule(rule)
        return
    if isinstance(envs, gym.vector.AsyncVectorEnv):
        raise ValueError("AsyncVectorEnv runs the routines in subprocesses, away from the "
                         "policy that would stop them")
    raise ValueError(f"{type(envs).__name__} has no stop rule (MinAtarVectorEnv and a "
                     "SyncVectorEnv of RoutineActionWrapper envs have one)")


def policy_stop_rule(logits: Callable[[Any], Any], margin: float | None,
                     device: Any) -> PolicyStopRule | None:
    """`--interrupt MARGIN`'s rule on the acting policy's `logits`, None when `margin` is None
    (every routine runs to its end): the training envs' (`interrupt_routines`) and the
    evaluation's, each a rule of its own with its own counts."""
    return None if margin is None else PolicyStopRule(logits, margin, device)


def interrupt_routines(envs: Any, logits: Callable[[Any], Any], margin: float | None,
                       device: Any) -> PolicyStopRule | None:
    """`--interrupt MARGIN`: give the training envs a `PolicyStopRule` on the acting policy's
    `logits` (None when `margin` is None: every routine runs to its end).

    Raises:
        UsageError: the envs cannot ask a rule (`set_stop_rule`), named as `--interrupt`'s.
    """
    rule = policy_stop_rule(logits, margin, device)
    if rule is None:
        return None
    from routine_gym.errors import UsageError

    try:
        set_stop_rule(envs, rule)
    except ValueError as exc:
        raise UsageError(f"--interrupt: {exc}") from None
    return rule
