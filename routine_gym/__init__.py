"""routine-gym: routine-augmented policy learning (RAPL) on Gymnasium.

Importing the package registers its envs (`MiniQbert-v0`, `procgen/CoinRun-v0`) with Gymnasium;
`register_envs()` adds ALE's (routine-gym calls it whenever it looks up or makes an env; call it
before a `gym.make("ALE/...")` of your own). Importing `routine_gym` thus never loads ALE or
Procgen. The pieces a user combines: record a `Demo` with `DemoRecorder`, mine a
`RoutineLibrary` from it with `SequiturMiner`, and act with routines through
`RoutineActionWrapper`.
"""

from routine_gym.demo import Demo, DemoRecorder
from routine_gym.envs import register_envs, register_own_envs
from routine_gym.library import RoutineLibrary
from routine_gym.mining import SequiturMiner
from routine_gym.wrapper import RoutineActionWrapper

register_own_envs()

__all__ = [
    "Demo",
    "DemoRecorder",
    "RoutineActionWrapper",
    "RoutineLibrary",
    "SequiturMiner",
    "register_envs",
]
__version__ = "0.1.0"
