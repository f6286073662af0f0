"""routine-gym: routine-augmented policy learning (RAPL) on Gymnasium."""

from routine_gym.envs import register_envs
from routine_gym.library import RoutineLibrary

register_envs()

__all__ = ["RoutineLibrary", "register_envs"]
__version__ = "0.1.0"
