"""Demonstrations: record, save, load, verify and replay the episodes RAPL learns from.

One module per idea; every public name is importable from `routine_gym.demo` itself.

- `routine_gym.demo.format`: the demonstration: `Demo`, `DemoEpisode`, which steps are
  decisions and which are injected, and its save and load.
- `routine_gym.demo.npz`: its file: the `.npz` format (versions 1 and 2, `DEMO_FORMAT`,
  `DEMO_VERSION`, `READABLE_VERSIONS`), the size limits a file must keep to (`MAX_*`), the
  checks it passes before it is read, and `demo_file_version`.
- `routine_gym.demo.recorder`: `DemoRecorder`, which records the raw env's steps as a `Demo`,
  and `DecisionMarker`, which tells it which steps the demonstrator decided.
- `routine_gym.demo.replay`: `replay`, which re-runs a demo from its seeds and verifies it
  (`ReplayResult`, `DemoReplayError`), and `upgrade_demo`, which rewrites a version-1 demo as
  version 2 by replaying it.
- `routine_gym.demo.collect`: demos from a trained agent (`record_agent_demo`) or a person at
  the keyboard (`record_human_demo`).
- `routine_gym.demo.suite`: the demos shipped with routine-gym: `DEMO_SUITE`, `DEMOS_DIR`,
  `demo_filename`, `shipped_demo_path`.
- `routine_gym.demo.minari`: Minari datasets: `export_minari` writes a demo as one,
  `load_minari_demo` reads one as a demo, and `read_demo` reads what a user names as a demo, a
  file or `minari:DATASET_ID` (`MINARI_SCHEME`).
"""

from routine_gym.demo.collect import record_agent_demo, record_human_demo
from routine_gym.demo.format import Demo, DemoEpisode
from routine_gym.demo.minari import MINARI_SCHEME, export_minari, load_minari_demo, read_demo
from routine_gym.demo.npz import DEMO_FORMAT, DEMO_VERSION, READABLE_VERSIONS, demo_file_version
from routine_gym.demo.recorder import DecisionMarker, DemoRecorder
from routine_gym.demo.replay import DemoReplayError, ReplayResult, replay, upgrade_demo
from routine_gym.demo.suite import (
    DEMO_SETS,
    DEMO_SUITE,
    DEMOS_DIR,
    demo_filename,
    demo_set_file,
    shipped_demo_path,
)

__all__ = [
    "DEMOS_DIR",
    "DEMO_SETS",
    "demo_set_file",
    "DEMO_FORMAT",
    "DEMO_SUITE",
    "DEMO_VERSION",
    "MINARI_SCHEME",
    "Demo",
    "DemoEpisode",
    "DemoRecorder",
    "DemoReplayError",
    "ReplayResult",
    "DecisionMarker",
    "READABLE_VERSIONS",
    "demo_file_version",
    "demo_filename",
    "export_minari",
    "load_minari_demo",
    "read_demo",
    "upgrade_demo",
    "record_agent_demo",
    "record_human_demo",
    "replay",
    "shipped_demo_path",
]
