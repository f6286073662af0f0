"""The env a script runs on, set up from its flags: the check that refuses an env the scripts
cannot handle (`check_env`), the keyword arguments of its training, evaluation and extra
evaluation levels (Procgen), and the env profile's reward scale where `--reward-scale` is left
unset. Part of `plumbing.run`'s set-up, which re-exports the public ones."""

from __future__ import annotations

from typing import Any

from routine_gym.errors import UsageError

__all__ = ["check_env", "eval_env_kwargs", "level_env_kwargs", "profile_reward_scale",
           "train_env_kwargs"]


def profile_reward_scale(args: Any) -> None:
    """Give a script's `--reward-scale` left unset (None) the env profile's
    `EnvProfile.reward_scale`; a given flag wins, a resumed run keeps its saved scale. An env
    id whose module cannot be imported is left to the run's env check, which names it (the
    scale is then 1)."""
    if not hasattr(args, "reward_scale") or args.reward_scale is not None:
        return
    from routine_gym.envs import profile_for

    try:
        args.reward_scale = profile_for(args.env_id).reward_scale
    except ImportError:
        args.reward_scale = 1.0


def check_env(env_id: str) -> None:
    """Refuse, before any work, an env the scripts cannot handle: one Gymnasium does not know,
    one whose actions are not `Discrete(n)` from 0, or whose observations are not a `Box`.

    Raises:
        UsageError: naming the env id and the problem (and the wrapper that would help).
    """
    import gymnasium as gym

    from routine_gym.envs import env_spec
    from routine_gym.envs.factory import make_primitive_env

    try:
        spec = env_spec(env_id)
    except ImportError as exc:
        raise UsageError(f"--env-id {env_id}: cannot import its module ({exc})") from None
    if spec is None:
        raise UsageError(f"--env-id {env_id}: Gymnasium does not know this env (a typo? for an "
                         "env of your own package, use the module:EnvId form)")
    env = make_primitive_env(env_id)
    try:
        actions, observations = env.action_space, env.observation_space
    finally:
        env.close()
    if not isinstance(actions, gym.spaces.Discrete):
        raise UsageError(f"--env-id {env_id} has the action space {actions}; routine-gym's "
                         "scripts need Discrete(n) actions")
    if int(actions.start) != 0:
        raise UsageError(f"--env-id {env_id} has the action space {actions}, which starts at "
                         f"{int(actions.start)}; routine-gym's scripts need Discrete(n) from 0 "
                         "(wrap it so its actions start at 0)")
    if not isinstance(observations, gym.spaces.Box):
        raise UsageError(f"--env-id {env_id} has the observation space {observations}; "
                         "routine-gym's networks take Box observations: register the env "
                         "wrapped in gymnasium.wrappers.FlattenObservation")


def train_env_kwargs(args: Any) -> dict[str, Any]:
    """The training levels of `args.env_id` (Procgen) from the script's level flags
    (`num_levels`, `start_level`, `distribution_mode`); other families have none."""
    from routine_gym.envs import profile_for

    return profile_for(args.env_id).level_kwargs(
        args.num_levels, args.start_level, args.distribution_mode, args.eval_distribution_mode,
        training=True)


def level_env_kwargs(args: Any, levels: str) -> dict[str, Any]:
    """The levels `--extra-evals` names: `train` (the training levels), or `easy`/`hard` (the
    unseen levels of that difficulty). Only for families with levels (Procgen).

    Raises:
        UsageError: `args.env_id`'s family has no levels.
    """
    from routine_gym.envs import profile_for

    profile = profile_for(args.env_id)
    if not profile.has_levels:
        raise UsageError(f"--extra-evals {levels}: {args.env_id} has no levels (only Procgen "
                         "envs do)")
    if levels == "train":
        return train_env_kwargs(args)
    return profile.level_kwargs(args.num_levels, args.start_level, args.distribution_mode,
                                levels, training=False)


def eval_env_kwargs(args: Any) -> dict[str, Any]:
    """The evaluation levels: Procgen's levels never trained on; other envs as in training."""
    from routine_gym.envs import profile_for

    return profile_for(args.env_id).level_kwargs(
        args.num_levels, args.start_level, args.distribution_mode, args.eval_distribution_mode,
        training=False)
