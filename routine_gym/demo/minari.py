"""Minari datasets: a demo exported as one, and one read back as a demo (`minari:DATASET_ID`).

Minari (Farama) is the format Gymnasium users share offline data in. `export_minari` writes a
demo into the local Minari folder (`MINARI_DATASETS_PATH`, else `~/.minari/datasets`) and
`load_minari_demo` reads a local dataset, routine-gym's own or anyone's, as a `Demo`. Nothing is
ever downloaded: a dataset that is not in the local folder is an error that says so. Both need
the optional `minari` package (`pip install routine-gym[minari]`); routine-gym imports it only
here, and only when a dataset is asked for.

An exported dataset
-------------------
- One Minari episode per demo episode: `observations` (T + 1: the observation before each
  action, then the final one), `actions`, `rewards`, `terminations`, `truncations`, and the
  episode's reset seed in its episode metadata (`seed`), Minari's own place for it. A demo that
  keeps no observations (the shipped ones) is replayed from its seeds to regenerate them,
  and the replay is checked step by step (`routine_gym.demo.replay`).
- **The decisions mask** is the per-step info `infos["decision"]`, laid out as Minari's
  `DataCollector` lays out infos: T + 1 rows, row 0 from the reset (False: no action), row
  `t + 1` the info of the step that took action `t` (True when the demonstrator chose it, False
  when a wrapper injected it). It is per-step data, so it goes with the steps: every Minari
  reader hands `EpisodeData.infos` to its user next to the actions, and an offline-RL user can
  drop the injected transitions without knowing routine-gym. Episode metadata is Minari's
  place for per-episode scalars (seed, options); a T-long mask does not belong there.
- **Metadata** (`metadata.json`): Minari's `env_spec` (the raw env the demo was recorded and
  replays on: its id, entry point and `gym.make` keyword arguments, time limit included),
  the observation and action spaces, `algorithm_name`, `description`, `requirements` (the
  env's package), and `routine_gym`: the demo's whole `meta` (seeds, action meanings, scores,
  source, training command, `recorded_under`, ...), the file it came from and when it was
  exported.

Storage backend
---------------
Minari's `arrow` backend. The numpy < 2 routine-gym needs (Procgen) pins Minari at 0.5.3, in
which both backends JPEG-encode observations of an image space (a uint8 Box of at least 32×32
with bounds 0–255: Atari's frames, CoinRun's) with no way to turn it off (`jpeg_encoding=False`
came in 0.5.4, which needs numpy 2), and in which `hdf5` also picks what to JPEG-encode by the
array written (any uint8 array of up to 3 dimensions, so Atari RAM, or a 7×7×3 grid) but what to
decode by the space, handing such observations back as JPEG bytes. `arrow` decides both by the
space and stores every other space exactly. For an image space routine-gym writes each frame as
PNG (lossless) into the column where Minari would put its JPEG: Minari decodes that column with
PIL, which reads PNG as well, so `minari.load_dataset(...)` returns the exact frames.

A dataset read as a demo
------------------------
Actions must be `Discrete(n)`. Episodes, rewards, flags and seeds come from the dataset; the
decisions from `infos["decision"]` when the dataset has them (a dataset without them counts
every step as a decision); observations are kept when the observation space is a `Box`; the
meta is the exported demo's when routine-gym wrote the dataset, else built from the env spec.
Nothing is unpickled (Minari's files are JSON and Arrow), and an env is never made from a
dataset's metadata while reading it.
"""

from __future__ import annotations

import contextlib
import importlib.metadata
import io
import os
import secrets
import shutil
import warnings
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from routine_gym.demo.format import Demo, _check_env, _routine_gym_version
from routine_gym.demo.npz import MAX_STEPS, _from_json, _to_json
from routine_gym.errors import UsageError

__all__ = [
    "MINARI_SCHEME",
    "check_minari_dataset",
    "export_minari",
    "load_minari_demo",
    "minari_dataset_id",
    "read_demo",
]

#: How a Minari dataset is named where a demo file is expected: `minari:DATASET_ID`.
MINARI_SCHEME = "minari:"
#: The key of routine-gym's own entry in a dataset's metadata.
METADATA_KEY = "routine_gym"
#: The per-step info that holds the decisions mask.
DECISION_INFO = "decision"
_EXPORT_FORMAT = "routine-gym/minari"
_INSTALL_HINT = "pip install routine-gym[minari]"
#: The variable that names the local Minari folder (Minari's own).
DATASETS_VARIABLE = "MINARI_DATASETS_PATH"
#: The longest name a file system takes for one folder of a dataset's path (Linux, macOS).
_NAME_MAX = 255


def minari_dataset_id(source: str | os.PathLike | None) -> str | None:
    """The dataset id of a `minari:DATASET_ID` source, or None for anything else (a file).

    Example:
        >>> minari_dataset_id("minari:routine-gym/qbert-v0"), minari_dataset_id("demo.npz")
        ('routine-gym/qbert-v0', None)
    """
    if not isinstance(source, str) or not source.startswith(MINARI_SCHEME):
        return None
    return source[len(MINARI_SCHEME):]


def read_demo(source: str | os.PathLike, env_id: str | None = None) -> Demo:
    """The demo a user named: a demo file (`Demo.load`) or a local Minari dataset
    (`minari:DATASET_ID`, `load_minari_demo`)."""
    dataset_id = minari_dataset_id(source)
    if dataset_id is None:
        return Demo.load(source, env_id=env_id)
    return load_minari_demo(dataset_id, env_id=env_id)


def _minari(what: str):
    """The `minari` package, with the Arrow support its datasets are written in, once the
    local Minari folder is one (`_check_datasets_root`); a UsageError that says how to install
    it when it is missing."""
    try:
        import minari
        import pyarrow  # noqa: F401  (Minari's arrow backend)
    except ImportError as exc:
        raise UsageError(f"{what} needs the optional minari package ({exc.name} is not "
                         f"installed): {_INSTALL_HINT}") from None
    _check_datasets_root()
    return minari


def _check_datasets_root() -> None:
    """Make a relative `MINARI_DATASETS_PATH` absolute, and refuse one that cannot be a folder.

    Minari reads the variable itself at every call. A relative one it joins onto itself when
    it writes an episode (`m/.x/data/m/.x/data/0`: every export failed), so it is made
    absolute for the rest of the process; a file on the way was a FileExistsError traceback
    from Minari's `os.makedirs`.

    Raises:
        UsageError: the variable is empty, or the folder (or one above it) is a file.
    """
    given = os.environ.get(DATASETS_VARIABLE)
    if given is not None:
        if not given.strip():
            raise UsageError(f"{DATASETS_VARIABLE} is empty: unset it (~/.minari/datasets) or "
                             "name the folder of the local Minari datasets")
        os.environ[DATASETS_VARIABLE] = os.path.abspath(os.path.expanduser(given))
    root = Path(os.environ.get(DATASETS_VARIABLE) or Path.home() / ".minari" / "datasets")
    for folder in (root, *root.parents):
        if folder.exists():
            if not folder.is_dir():
                named = f"{DATASETS_VARIABLE}={given}" if given is not None else str(root)
                raise UsageError(f"{named}: {folder} is a file, not a folder; the local Minari "
                                 "datasets cannot be there")
            return


def _check_dataset_id(dataset_id: str) -> None:
    """Refuse an id Minari would not parse, or whose folder names the file system refuses."""
    from minari.dataset.minari_dataset import parse_dataset_id

    too_long = [part for part in dataset_id.split("/") if len(os.fsencode(part)) > _NAME_MAX]
    if too_long:  # Minari would parse it, then the first stat was an OSError traceback
        raise UsageError(f"Minari dataset id {dataset_id[:40]}...: a part of "
                         f"{len(too_long[0])} characters, longer than a file name may be "
                         f"({_NAME_MAX} bytes)")
    try:
        parse_dataset_id(dataset_id)  # raises ValueError, or TypeError for a missing version
    except (ValueError, TypeError):
        raise UsageError(f"{dataset_id!r} is not a Minari dataset id: it takes the form "
                         "(namespace/)name-vVERSION, e.g. routine-gym/qbert-expert-v0") from None


# -- export -------------------------------------------------------------------------------


def export_minari(demo: Demo, dataset_id: str, *, source: str | None = None) -> Path:
    """Write `demo` as the local Minari dataset `dataset_id` (the layout in the module's
    docstring); the dataset's folder.

    The dataset is built in a hidden folder of the Minari root and renamed into place once
    complete, so a failed or interrupted export leaves no dataset behind.

    Args:
        demo: the demo. Without observations it is replayed from its seeds to regenerate
            them (and checked), so it needs an env id and a seed per episode.
        dataset_id: the new dataset's id, `(namespace/)name-vVERSION`; it must not exist.
        source: where the demo came from (its file), kept in the dataset's metadata.

    Raises:
        UsageError: minari is not installed, the id is malformed or taken, or the demo has no
            env id or observations that do not fit its env's observation space.
        routine_gym.demo.DemoReplayError: the replay that regenerates the observations
            diverged from the demo.
    """
    minari = _minari("exporting a Minari dataset")
    from minari.dataset.minari_storage import MinariStorage
    from minari.storage.datasets_root_dir import get_dataset_path

    _check_dataset_id(dataset_id)
    target = get_dataset_path(dataset_id)
    _check_no_nesting(dataset_id, target, get_dataset_path())
    if target.exists():
        raise UsageError(f"Minari dataset {dataset_id} already exists at {target}; choose "
                         "another id (or version), or delete it (`minari delete "
                         f"{dataset_id}`)")
    if demo.env_id is None:
        raise UsageError("the demo has no env id (it was recorded on an env not made by "
                         "gym.make), so its dataset can name no env: Minari needs one")
    env = _raw_env(demo)
    observation_space, action_space, env_spec = env.observation_space, env.action_space, env.spec
    env.close()
    with_observations = demo if demo.has_observations else _replayed(demo)
    _check_observations(with_observations, observation_space)

    # Hidden (Minari lists no folder starting with "."), beside the target's root, so the
    # rename is one step on one file system.
    staging = get_dataset_path() / f".routine-gym-export-{os.getpid()}-{secrets.token_hex(6)}"
    staging.mkdir()
    try:
        with warnings.catch_warnings():  # Minari's advice on optional metadata is not ours
            warnings.simplefilter("ignore")
            storage = MinariStorage.new(staging / "data", observation_space=observation_space,
                                        action_space=action_space, env_spec=env_spec,
                                        data_format="arrow")
            storage.update_metadata(_dataset_metadata(demo, dataset_id, env_spec, source,
                                                      minari.__version__))
            _write_episodes(storage, with_observations, demo.decisions)
        _move_into_place(staging, target, dataset_id)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return target


def _check_no_nesting(dataset_id: str, target: Path, root: Path) -> None:
    """Refuse an id whose folder lies inside an existing dataset (`rg/mq-v0/sub-v0` when
    `rg/mq-v0` exists), or is a namespace holding datasets (`rg` when `rg/mq-v0` exists)."""
    parts = target.relative_to(root).parts
    for k in range(1, len(parts)):
        above = root.joinpath(*parts[:k])
        if (above / "data").is_dir():
            raise UsageError(f"Minari dataset id {dataset_id} would put a dataset inside the "
                             f"dataset {'/'.join(parts[:k])} ({above}); choose an id outside it")
    if target.is_dir() and not (target / "data").is_dir():
        raise UsageError(f"Minari dataset id {dataset_id} is a folder of other datasets "
                         f"({target}), not a free id; choose another id")


def _raw_env(demo: Demo):
    """The env the demo was recorded on, as `replay` makes it."""
    from routine_gym.envs import make_env

    kwargs = demo.env_kwargs
    if demo.meta.get("max_episode_steps") is not None:
        kwargs["max_episode_steps"] = demo.meta["max_episode_steps"]
    return make_env(demo.env_id, **kwargs)


def _replayed(demo: Demo) -> Demo:
    """`demo` with the observations of its replay (checked against every reward and flag)."""
    from routine_gym.demo.replay import replay

    if any(seed is None for seed in demo.seeds):
        raise UsageError("the demo keeps no observations and has no reset seed for every "
                         "episode, so its observations cannot be replayed for the dataset")
    return replay(demo, record_observations=True).demo


def _check_observations(demo: Demo, space: Any) -> None:
    from gymnasium import spaces

    obs = demo.observations
    if not isinstance(space, spaces.Box) or obs.shape[1:] != space.shape or (
            obs.dtype != space.dtype):
        raise UsageError(f"the demo's observations are {obs.dtype}{list(obs.shape[1:])}, not "
                         f"the env's observation space {space}")


def _requirements(env_spec: Any) -> list[str]:
    """The distribution that provides the env's entry point, at its installed version."""
    entry = env_spec.entry_point
    module = entry.partition(":")[0] if isinstance(entry, str) else entry.__module__
    top = module.split(".")[0]
    found = []
    for dist in importlib.metadata.packages_distributions().get(top, []):
        with contextlib.suppress(importlib.metadata.PackageNotFoundError):
            found.append(f"{dist}=={importlib.metadata.version(dist)}")
    return sorted(set(found))


def _dataset_metadata(demo: Demo, dataset_id: str, env_spec: Any, source: str | None,
                      minari_version: str) -> dict[str, Any]:
    meta = demo.meta
    algorithm = f"routine-gym demo: {meta['source']}"
    if meta.get("mode"):
        algorithm += f" ({meta['mode']})"
    scores = ", ".join(f"{s:g}" for s in demo.scores)
    description = (
        f"A demonstration of {demo.env_id} exported by routine-gym"
        + (f" from {source}" if source else "")
        + f": {demo.num_episodes} episode(s), {len(demo)} steps ({demo.num_decisions} decided "
        f"by the demonstrator, {demo.num_injected} injected by wrappers), scores {scores}. "
        f"infos['{DECISION_INFO}'][t + 1] is True when the demonstrator chose action t. The "
        "whole demo's meta is under 'routine_gym'."
    )
    return {
        "dataset_id": dataset_id,
        "minari_version": minari_version,
        "algorithm_name": algorithm,
        "description": description,
        "requirements": _requirements(env_spec),
        METADATA_KEY: {
            "format": _EXPORT_FORMAT,
            "version": 1,
            "demo": _to_json(meta),
            "exported_from": source,
            "exported": datetime.now(UTC).isoformat(timespec="seconds"),
            "routine_gym_version": _routine_gym_version(),
            "decisions": f"infos['{DECISION_INFO}'], row t + 1 for action t (row 0: the reset)",
            "observations": "recorded" if demo.has_observations else "replayed from the seeds",
        },
    }


def _write_episodes(storage: Any, demo: Demo, decisions: np.ndarray) -> None:
    """The demo's episodes into `storage`: through Minari's own writer, except for an image
    space, whose frames are written as PNG (see the module docstring)."""
    from minari.data_collector.episode_buffer import EpisodeBuffer
    from minari.dataset.minari_storage import is_image_space

    buffers = []
    for e in range(demo.num_episodes):
        ep = demo.episode(e)
        start = int(demo.episode_offsets[e])
        decided = decisions[start:start + len(ep)]
        buffers.append(EpisodeBuffer(
            seed=ep.seed,
            observations=np.concatenate([ep.observations, ep.final_observation[None]]),
            actions=ep.actions,
            rewards=ep.rewards,
            terminations=ep.terminated,
            truncations=ep.truncated,
            # Python bools: Minari 0.5.3 cannot read back a 1-D NumPy array of infos.
            infos={DECISION_INFO: [False, *decided.tolist()]},
        ))
    if is_image_space(storage.observation_space):
        _write_png_episodes(storage, buffers)
    else:
        storage.update_episodes(buffers)


def _png(frame: np.ndarray) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(frame).save(buffer, format="PNG")
    return buffer.getvalue()


def _write_png_episodes(storage: Any, buffers: list[Any]) -> None:
    """Minari's arrow layout (one folder per episode: the steps as one Arrow file, padded to
    T + 1 rows, and `metadata.json`), with the image column as PNG instead of JPEG."""
    import pyarrow as pa
    import pyarrow.dataset as ds
    from PIL import Image

    first = buffers[0].observations[0]
    decoded = np.array(Image.open(io.BytesIO(_png(first))))
    if decoded.shape != first.shape or not np.array_equal(decoded, first):
        raise UsageError(f"observations of shape {first.shape} cannot be stored as images; "
                         "Minari stores this observation space only as images")
    total_steps = 0
    for episode_id, buffer in enumerate(buffers):
        steps = len(buffer.rewards)
        total_steps += steps
        columns = {
            "episode_id": np.full(steps + 1, episode_id, dtype=np.int32),
            "observations": pa.array([_png(frame) for frame in buffer.observations],
                                     type=pa.binary()),
            "actions": pa.array(np.append(buffer.actions, 0),
                                type=pa.from_numpy_dtype(storage.action_space.dtype)),
            "rewards": np.append(buffer.rewards, 0.0),
            "terminations": np.append(buffer.terminations, False),
            "truncations": np.append(buffer.truncations, False),
            "infos": pa.StructArray.from_arrays(
                [pa.array(buffer.infos[DECISION_INFO], type=pa.bool_())],
                names=[DECISION_INFO]),
        }
        ds.write_dataset(pa.RecordBatch.from_pydict(columns), storage.data_path,
                         format="arrow", partitioning=["episode_id"],
                         existing_data_behavior="overwrite_or_ignore")
        episode_meta: dict[str, Any] = {"id": episode_id, "total_steps": steps}
        if buffer.seed is not None:
            episode_meta["seed"] = int(buffer.seed)
        storage.update_episode_metadata([episode_meta], [episode_id])
    storage.update_metadata({"total_steps": total_steps, "total_episodes": len(buffers),
                             "dataset_size": storage.get_size()})


def _move_into_place(staging: Path, target: Path, dataset_id: str) -> None:
    """Rename the finished dataset to its place, making its namespace when it has one."""
    from minari.dataset.minari_dataset import parse_dataset_id
    from minari.namespace import create_namespace, list_local_namespaces

    namespace = parse_dataset_id(dataset_id)[0]
    if namespace is not None and namespace not in list_local_namespaces():
        create_namespace(namespace)
    try:
        os.rename(staging, target)
    except OSError as exc:  # another export took the id meanwhile
        raise UsageError(f"cannot create Minari dataset {dataset_id} at {target}: "
                         f"{exc.strerror}") from None


# -- import -------------------------------------------------------------------------------


def load_minari_demo(dataset_id: str, env_id: str | None = None) -> Demo:
    """The local Minari dataset `dataset_id` as a `Demo` (what is kept: the module docstring).

    Args:
        dataset_id: the dataset's id, as `minari.load_dataset` takes it.
        env_id: when given, the dataset must have been recorded on this env (when it names
            one).

    Raises:
        UsageError: minari is not installed, the id is malformed, or the dataset is not one a
            demo can be read from (actions not `Discrete`, no spaces, too many steps, a bad
            decisions mask), or it was recorded on another env; each names the dataset.
        FileNotFoundError: no such dataset in the local Minari folder.
    """
    minari = _minari(f"{MINARI_SCHEME}{dataset_id}")
    from minari.serialization import deserialize_space

    name = f"{MINARI_SCHEME}{dataset_id}"
    raw = check_minari_dataset(dataset_id)
    try:
        # Without its spaces Minari would make the dataset's env to find them, running code
        # named by the file; a demo needs them anyway.
        if "observation_space" not in raw or "action_space" not in raw:
            raise UsageError("its metadata names no observation or action space")
        action_space = deserialize_space(raw["action_space"])
        _check_actions(action_space)
        if int(raw.get("total_steps", 0)) > MAX_STEPS:
            raise UsageError(f"it holds {raw['total_steps']:,} steps, over the limit of "
                             f"{MAX_STEPS:,} a demo may hold")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            dataset = minari.load_dataset(dataset_id)
            episodes = list(dataset.iterate_episodes())
            seeds = [m.get("seed") for m in
                     dataset.storage.get_episode_metadata(dataset.episode_indices)]
        demo = _demo(raw, dataset, episodes, seeds, dataset_id)
    except ValueError as exc:  # ours, the Demo's checks, Minari's and Arrow's (ArrowInvalid)
        raise UsageError(f"{name}: {exc}") from exc
    except ImportError as exc:  # a backend's package (checked above for hdf5)
        raise UsageError(f"{name}: reading it needs {exc.name or 'a package'}, which is not "
                         f"installed ({exc})") from None
    except (TypeError, KeyError, OSError) as exc:
        raise UsageError(f"{name}: not a dataset routine-gym can read "
                         f"({type(exc).__name__}: {exc})") from exc
    try:
        _check_env(demo, env_id=env_id)
    except ValueError as exc:
        raise UsageError(f"{name}: {exc}") from None
    return demo


def check_minari_dataset(dataset_id: str) -> dict[str, Any]:
    """Refuse, before any work (a script checks `--demo minari:ID` before it makes its run
    folder), a dataset that cannot be read here: minari not installed, a malformed id, no such
    local dataset, or one stored in Minari's `hdf5` format (its default) without `h5py`.
    Returns the dataset's raw metadata.

    Raises:
        UsageError: one line naming the dataset and what to do.
        FileNotFoundError: no such dataset in the local Minari folder.
    """
    _minari(f"{MINARI_SCHEME}{dataset_id}")
    from minari.dataset.minari_storage import MinariStorage
    from minari.storage.datasets_root_dir import get_dataset_path

    name = f"{MINARI_SCHEME}{dataset_id}"
    _check_dataset_id(dataset_id)
    data_path = get_dataset_path(dataset_id) / "data"
    if not data_path.is_dir():
        raise FileNotFoundError(
            f"{name}: no Minari dataset {dataset_id} in {get_dataset_path()} (set "
            "MINARI_DATASETS_PATH to the folder that holds it; routine-gym never downloads "
            "one)")
    try:
        raw = MinariStorage.read_raw_metadata(data_path)
    except ValueError as exc:
        raise UsageError(f"{name}: {exc}") from exc
    except (TypeError, KeyError, OSError) as exc:
        raise UsageError(f"{name}: not a dataset routine-gym can read "
                         f"({type(exc).__name__}: {exc})") from exc
    if not isinstance(raw, dict):
        raise UsageError(f"{name}: its metadata is not a JSON object")
    data_format = raw.get("data_format")
    if data_format == "hdf5":
        try:
            import h5py  # noqa: F401  (Minari's hdf5 backend)
        except ImportError:
            raise UsageError(
                f"{name} is stored in Minari's hdf5 format, which needs h5py (not installed): "
                "pip install 'minari[hdf5]' into routine-gym's venv, or re-create the dataset "
                "with data_format='arrow' (what `routine-gym export` writes)") from None
    elif data_format not in (None, "arrow"):
        raise UsageError(f"{name} is stored in the format {data_format!r}; routine-gym reads "
                         "Minari's arrow and hdf5 formats")
    return raw


def _check_actions(space: Any) -> None:
    from gymnasium import spaces

    if not isinstance(space, spaces.Discrete) or int(space.start) != 0:
        raise UsageError(f"a demo's actions are Discrete(n); the dataset's action space is "
                         f"{space}")


def _demo(raw: dict[str, Any], dataset: Any, episodes: list[Any], seeds: list[Any],
          dataset_id: str) -> Demo:
    """A `Demo` of the dataset's episodes (read by Minari) and its raw metadata."""
    from gymnasium import spaces

    if not episodes:
        raise UsageError("it holds no episode")
    lengths = [len(ep) for ep in episodes]
    if min(lengths) < 1:
        raise UsageError(f"episode {lengths.index(min(lengths))} has no step")
    decisions = []
    for e, ep in enumerate(episodes):
        infos = ep.infos or {}
        if DECISION_INFO not in infos:
            decisions.append(np.ones(len(ep), dtype=np.bool_))
            continue
        mask = np.asarray(infos[DECISION_INFO])
        if mask.shape != (len(ep) + 1,) or mask.dtype != np.bool_:
            raise UsageError(f"episode {e}'s infos['{DECISION_INFO}'] is {mask.dtype} of shape "
                             f"{mask.shape}, not the {len(ep) + 1} booleans of a decisions mask")
        decisions.append(mask[1:])
    observations = final_observations = None
    space = dataset.observation_space
    if isinstance(space, spaces.Box) and all(
            isinstance(ep.observations, np.ndarray)
            and ep.observations.shape == (len(ep) + 1, *space.shape) for ep in episodes):
        observations = np.concatenate([ep.observations[:-1] for ep in episodes])
        final_observations = np.stack([ep.observations[-1] for ep in episodes])
    ours = raw.get(METADATA_KEY)
    if isinstance(ours, dict) and ours.get("format") == _EXPORT_FORMAT:
        meta = _from_json(ours["demo"])
        if not isinstance(meta, dict):
            raise UsageError(f"its '{METADATA_KEY}' metadata holds no demo meta")
        stored_scores = meta.pop("scores", None)
    else:
        meta, stored_scores = _foreign_meta(dataset, raw), None
    meta = {**meta, "seeds": [None if s is None else int(s) for s in seeds],
            "num_actions": int(dataset.action_space.n), "minari_dataset": dataset_id}
    demo = Demo(
        actions=np.concatenate([np.asarray(ep.actions).reshape(-1) for ep in episodes]),
        rewards=np.concatenate([np.asarray(ep.rewards, dtype=np.float64) for ep in episodes]),
        terminated=np.concatenate([np.asarray(ep.terminations) for ep in episodes]),
        truncated=np.concatenate([np.asarray(ep.truncations) for ep in episodes]),
        episode_lengths=np.array(lengths, dtype=np.int64),
        observations=observations,
        final_observations=final_observations,
        meta=meta,
        decisions=np.concatenate(decisions),
    )
    if stored_scores is not None and not np.allclose(stored_scores, demo.scores, rtol=1e-9,
                                                     atol=1e-9):
        raise UsageError(f"the scores of its demo meta {stored_scores} disagree with its "
                         f"rewards, which sum to {demo.scores.tolist()}")
    return demo


def _foreign_meta(dataset: Any, raw: dict[str, Any]) -> dict[str, Any]:
    """A demo's meta for a dataset routine-gym did not write: its env from the env spec."""
    spec = dataset.env_spec
    meta: dict[str, Any] = {"source": "minari", "env_id": None, "env_kwargs": {}}
    if spec is not None:
        kwargs = {k: v for k, v in spec.kwargs.items() if k != "render_mode"}
        meta.update(env_id=spec.id, env_kwargs=kwargs, max_episode_steps=spec.max_episode_steps)
    for key in ("algorithm_name", "author", "description", "minari_version"):
        if raw.get(key) is not None:
            meta[f"minari_{key}"] = raw[key]
    return meta
