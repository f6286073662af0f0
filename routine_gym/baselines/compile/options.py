"""CompILE's latent codes as options: `CompILEOptions` (the codes with the decoder and the
termination head, on the CPU), `OptionActionWrapper` (the options as macro-actions of an env)
and `option_primitive_policy` (the same options played one primitive step a call, for
evaluation). How an option runs, and why greedily, is in the package docstring.
"""

from __future__ import annotations

import contextlib
import copy
from collections.abc import Callable, Iterator, Sequence
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces

from routine_gym.baselines.compile.model import CompILE
from routine_gym.macro_info import new_step_arrays, write_routine_info

__all__ = ["CompILEOptions", "OptionActionWrapper", "option_primitive_policy"]


@contextlib.contextmanager
def _one_thread() -> Iterator[None]:
    """A batch of one is fastest on one thread, and leaves the other cores to the learner."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


class CompILEOptions:
    """K latent codes of a trained CompILE model as options, evaluated on the CPU.

    `evaluate(obs, k)` gives option `k`'s greedy action `argmax_a π(a | obs, z_k)` and its
    termination probability `β(obs, z_k)` in one forward pass of one observation, without
    gradients and on one thread.

    Args:
        model: the trained model (copied to the CPU; the original is left as it is).
        codes: the codes that become options, option `k` being `codes[k]`.
    """

    def __init__(self, model: CompILE, codes: Sequence[int]) -> None:
        z = model.config.num_latents
        bad = [c for c in codes if not 0 <= int(c) < z]
        if bad:
            raise ValueError(f"code {bad[0]} is not one of the model's {z} latent codes")
        if len(codes) == 0:
            raise ValueError("options need at least one code")
        self.model = copy.deepcopy(model).cpu().eval()
        self.codes = tuple(int(c) for c in codes)
        self._latents = torch.eye(z)[list(self.codes)]

    def __len__(self) -> int:
        return len(self.codes)

    def evaluate(self, obs: Any, k: int) -> tuple[int, float]:
        """Option `k`'s greedy action at `obs` and its termination probability there."""
        with torch.no_grad(), _one_thread():
            features = self.model.features(torch.as_tensor(np.asarray(obs)[None]))
            z = self._latents[k: k + 1]
            action = int(self.model.policy_logits(features, z).argmax(dim=-1)[0])
            beta = float(torch.sigmoid(self.model.termination_logits(features, z))[0])
        return action, beta


def _option_action(options: Any, k: int, obs: Any, executed: int, max_length: int) -> int | None:
    """The next primitive action of option `k` after `executed` steps, or None when it ends at
    `obs` (the termination head fires there, or it has run `max_length` steps). The first step
    always runs."""
    if executed >= max_length:
        return None
    action, beta = options.evaluate(obs, k)
    if executed > 0 and beta > 0.5:
        return None
    return action


class OptionActionWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Extends a `Discrete(n)` env with `K` CompILE options to `Discrete(n + K)`.

    Action `a < n` is the primitive `a`; action `n + k` runs option `k`: its greedy decoder
    action at the current observation, one inner `env.step` each, until the termination head
    fires on the observation reached (`β > 0.5`; never after zero steps), `max_length` steps
    have run, or the episode terminates or is truncated. Like `RoutineActionWrapper`, the
    reward is the plain sum of the executed steps' rewards and `info` is the last inner info
    extended with the ``routine_*`` keys of `routine_gym.macro_info` (the contract the two
    wrappers share, so the MacroAction learner of `algos/rapl_a2c.py` and `algos/compile_a2c.py`
    reads either): the option's index (`-1` for a primitive action), the primitive steps it
    executed (`1 ≤ ℓ ≤ max_length`), and their actions, rewards and flags.

    Every array has length `max_length`, so `SyncVectorEnv`/`AsyncVectorEnv` stack them. Unlike
    a routine, an option's actions depend on the observations, so the wrapper keeps the last
    observation (from `reset` and `step`) to act on.

    Example:
        >>> import gymnasium as gym
        >>> class PushRightTwice:  # option 0: action 1, ends on the state after two steps
        ...     def __init__(self): self.steps = 0
        ...     def __len__(self): return 1
        ...     def evaluate(self, obs, k):
        ...         self.steps += 1
        ...         return 1, float(self.steps == 3)
        >>> env = OptionActionWrapper(gym.make("CartPole-v1"), PushRightTwice(), max_length=5)
        >>> env.action_space
        Discrete(3)
        >>> _ = env.reset(seed=0)
        >>> _, reward, _, _, info = env.step(2)
        >>> reward, info["routine_length"], info["routine_actions"].tolist()
        (2.0, 2, [1, 1, -1, -1, -1])

    Args:
        env: an env with a `Discrete(n)` action space starting at 0.
        options: the options, e.g. `CompILEOptions`: `len(options)` is K and
            `options.evaluate(obs, k)` gives option `k`'s action at `obs` and its termination
            probability there.
        max_length: the most primitive steps an option runs (CompILE: twice the longest
            segment of its codes).

    Raises:
        TypeError: the action space is not `Discrete`.
        ValueError: it does not start at 0, there are no options, or `max_length < 1`.
    """

    def __init__(self, env: gym.Env, options: Any, max_length: int) -> None:
        space = env.action_space
        if not isinstance(space, spaces.Discrete):
            raise TypeError("OptionActionWrapper needs an env with a Discrete action space, "
                            f"actual action space: {space!r}")
        if int(space.start) != 0:
            raise ValueError("OptionActionWrapper needs a Discrete action space starting at 0, "
                             f"actual action space: {space!r}")
        if len(options) < 1:
            raise ValueError("OptionActionWrapper needs at least one option, actual: 0")
        if int(max_length) < 1:
            raise ValueError(f"max_length needs to be ≥ 1, actual value: {max_length}")
        gym.utils.RecordConstructorArgs.__init__(self, options=options,
                                                 max_length=int(max_length))
        gym.Wrapper.__init__(self, env)
        self.options = options
        self.num_primitive_actions = int(space.n)
        self.max_length = int(max_length)
        self.action_space = spaces.Discrete(self.num_primitive_actions + len(options))
        self._obs: Any = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self._obs = obs
        return obs, info

    def step(self, action: int) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        """Run the primitive or option `action`; see the class docstring."""
        a = int(action)
        if not self.action_space.contains(a):
            raise ValueError(f"action {action!r} is outside the action space {self.action_space}")
        n, length = self.num_primitive_actions, self.max_length
        actions, rewards, terminated_steps, truncated_steps = new_step_arrays(length)
        executed, total = 0, 0.0
        primitive: int | None = a if a < n else _option_action(self.options, a - n, self._obs,
                                                               0, length)
        while primitive is not None:
            obs, reward, terminated, truncated, info = self.env.step(primitive)
            self._obs = obs
            actions[executed], rewards[executed] = primitive, float(reward)
            terminated_steps[executed], truncated_steps[executed] = terminated, truncated
            total += float(reward)
            executed += 1
            if a < n or terminated or truncated:
                break
            primitive = _option_action(self.options, a - n, obs, executed, length)
        write_routine_info(info, a - n if a >= n else -1, executed, actions, rewards,
                           terminated_steps, truncated_steps)
        return obs, total, terminated, truncated, info

    def get_action_meanings(self) -> list[str]:
        """The inner env's action names (or ids), then `"O{k}"` (`"O{k}:z{code}"` for CompILE)."""
        n = self.num_primitive_actions
        inner = getattr(self.env.unwrapped, "get_action_meanings", None)
        meanings = [str(m) for m in inner()] if callable(inner) else None
        if meanings is None or len(meanings) != n:
            meanings = [str(i) for i in range(n)]
        codes = getattr(self.options, "codes", None)
        return meanings + [f"O{k}" + (f":z{codes[k]}" if codes is not None else "")
                           for k in range(len(self.options))]


def option_primitive_policy(
    controller: Callable[[np.ndarray], int], options: Any, max_length: int, num_actions: int
) -> Callable[[np.ndarray, gym.Env], int]:
    """A policy of primitive actions that runs a controller's options itself, one step a call.

    For `routine_gym.plumbing.evaluation.evaluate_policy` (and `record_agent_demo`), which take a
    policy of the env's own actions: when `controller(obs)` picks `num_actions + k`, the
    returned policy plays option `k`'s steps on the following calls exactly as
    `OptionActionWrapper` would, and asks the controller again when the option ends. The
    policy is called as `policy(obs, env)`; a new episode (the env's `RecordEpisodeStatistics`
    counts them, as `algos/option_critic.py` reads) ends the running option.
    """
    state = {"option": None, "executed": 0, "episode": None}

    def policy(obs: np.ndarray, env: gym.Env) -> int:
        episode = env.get_wrapper_attr("episode_count")
        if episode != state["episode"]:
            state.update(option=None, episode=episode)
        if state["option"] is not None:
            action = _option_action(options, state["option"], obs, state["executed"],
                                    max_length)
            if action is not None:
                state["executed"] += 1
                return action
            state["option"] = None
        choice = int(controller(obs))
        if choice < num_actions:
            return choice
        state.update(option=choice - num_actions, executed=1)
        return _option_action(options, choice - num_actions, obs, 0, max_length)

    return policy
