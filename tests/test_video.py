"""`--capture-video` (routine_gym/video.py): every script that has it films and evaluates, a
filmed episode's frames wait on disk (memory bounded whatever the episode's length), the GIF is
written frame by frame, and a resumed run never overwrites its first leg's films (issue 46)."""

from __future__ import annotations

import dataclasses
import hashlib
import subprocess
import sys
import tracemalloc
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from PIL import Image
from script_loader import ALGOS, load_script

from routine_gym.envs.factory import make_env
from routine_gym.video import FrameRecorder, FrameSpool, unused_path, write_gif

BIN = Path(sys.executable).parent
NAMES = sorted(path.stem for path in ALGOS.glob("*.py"))
#: The scripts with a --capture-video flag, found from their `Args` (a new one is tested too).
FILMING = [name for name in NAMES
           if "capture_video" in {f.name for f in dataclasses.fields(
               load_script(name, f"video_{name}").Args)}]


class Screen(gym.Env):
    """An env of `length` steps whose frame `t` is filled with the value `t % 256`."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, length: int = 5, shape: tuple[int, int] = (40, 32)) -> None:
        self.render_mode = "rgb_array"
        self.length, self.shape = length, shape
        self.observation_space = gym.spaces.Box(0, 1, (1,))
        self.action_space = gym.spaces.Discrete(2)
        self.t = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(1, np.float32), {}

    def step(self, action):
        self.t += 1
        return np.zeros(1, np.float32), 0.0, self.t >= self.length, False, {}

    def render(self):
        return np.full((*self.shape, 3), self.t % 256, np.uint8)


def play(env: gym.Env, episodes: int) -> None:
    for _ in range(episodes):
        env.reset()
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(0)
            done = terminated or truncated


# -- the frames on disk, the GIF streamed ------------------------------------------------------


def test_a_spool_gives_back_each_frame_at_the_gifs_width(tmp_path):
    spool = FrameSpool(tmp_path)
    for value in (0, 7, 255):
        spool.append(np.full((10, 16, 4), value, np.uint8))  # RGBA: the alpha is dropped
    assert len(spool) == 3 and spool[1].shape == (200, 320, 3)
    assert [int(frame[0, 0, 0]) for frame in spool] == [0, 7, 255] == [int(spool[i].max())
                                                                       for i in (-3, -2, -1)]
    assert list(tmp_path.iterdir()) == []  # the file has no name: nothing to clean up
    with pytest.raises(ValueError, match="a frame of shape"):
        spool.append(np.zeros((20, 16, 3), np.uint8))
    spool.close()
    assert len(spool) == 0


def test_a_long_episode_holds_a_bounded_number_of_frames_in_memory(tmp_path):
    # 3,001 frames of 40 × 320 pixels are 115 MB: kept in a list (as before issue 46) the
    # recorder's peak would be that much; spooled to disk and streamed, it is a few frames.
    written = {}

    def write(episode, frames, actions):
        written[episode] = len(frames)
        write_gif(frames, [f"step {t}" for t in range(len(frames))], tmp_path / "long.gif")

    env = FrameRecorder(Screen(length=3_000, shape=(40, 320)), on_episode_end=write,
                        spool_dir=tmp_path)
    tracemalloc.start()
    try:
        play(env, 1)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    frame_bytes = 40 * 320 * 3
    assert written == {0: 3_001}
    assert peak < 100 * frame_bytes, f"peak {peak / 1e6:.1f} MB"  # not 3,001 frames
    with Image.open(tmp_path / "long.gif") as gif:
        assert gif.n_frames == 3_001  # every frame differs (its caption)
    assert [p.name for p in tmp_path.iterdir()] == ["long.gif"]  # the spool is gone


def test_write_gif_gives_each_frame_its_palette_its_caption_and_its_delay(tmp_path):
    colours = [(255, 0, 0), (0, 255, 0), (0, 255, 0), (0, 0, 255)]
    frames = [np.full((8, 16, 3), c, np.uint8) for c in colours]
    write_gif(frames, ["a", "b", "b", "c"], tmp_path / "x.gif", fps=10)
    with Image.open(tmp_path / "x.gif") as gif:
        # Frames 1 and 2 are identical, caption included: one frame shown twice as long.
        assert gif.n_frames == 3 and gif.size == (320, 160 + 22)
        durations, tops = [], []
        for k in range(gif.n_frames):
            gif.seek(k)
            durations.append(gif.info["duration"])
            tops.append(tuple(np.asarray(gif.convert("RGB"))[0, 0]))
        assert gif.info.get("loop") == 0
    assert durations == [100, 200, 100]  # 1000 / fps ms, in GIF's hundredths of a second
    assert tops == [colours[0], colours[1], colours[3]]


def test_write_gif_refuses_a_caption_count_that_does_not_match(tmp_path):
    with pytest.raises(ValueError, match="one caption per frame"):
        write_gif([np.zeros((4, 4, 3), np.uint8)], [], tmp_path / "x.gif")


def test_a_filmed_evaluation_calls_a_two_argument_policy_with_its_env(tmp_path):
    # The class behind issue 46's compile_a2c crash: filming wraps the policy, and the wrapper
    # must call it as record_agent_demo would, `policy(obs, env)` when it takes two.
    from routine_gym.plumbing.evaluation import evaluate_policy

    envs_seen = []

    def policy(obs, env):
        envs_seen.append(env)
        return 0

    summary = evaluate_policy("MiniQbert-v0", policy, 1, seed=0, max_steps=20,
                              video_folder=str(tmp_path))
    assert summary["lengths"] == [20] and len(envs_seen) == 20
    assert isinstance(envs_seen[0], gym.Env) and all(e is envs_seen[0] for e in envs_seen)
    with Image.open(tmp_path / "eval-episode-0.gif") as gif:
        assert 1 < gif.n_frames <= 21  # a frame a step and one after (identical ones merged)
    assert [p.name for p in tmp_path.iterdir()] == ["eval-episode-0.gif"]  # no spool left


# -- numbering: a resumed run goes on, nothing is overwritten ---------------------------------


def test_an_unused_path_never_names_an_existing_file(tmp_path):
    first = tmp_path / "train-episode-27.gif"
    assert unused_path(first) == str(first)
    first.write_bytes(b"leg 1")
    assert unused_path(first) == str(tmp_path / "train-episode-27-2.gif")
    (tmp_path / "train-episode-27-2.gif").write_bytes(b"leg 2")
    assert unused_path(first) == str(tmp_path / "train-episode-27-3.gif")


def test_the_recorder_numbers_episodes_from_its_first_episode():
    seen = []
    env = FrameRecorder(Screen(length=2), on_episode_end=lambda k, frames, actions:
                        seen.append((k, len(frames), actions)), first_episode=26)
    assert env.episode == 25
    play(env, 3)
    assert seen == [(26, 3, [0, 0]), (27, 3, [0, 0]), (28, 3, [0, 0])]


def test_the_training_film_of_a_resumed_run_goes_on_numbering_and_keeps_old_files(
        tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # training films go to ./videos/{run_name}/, as CleanRL's
    folder = tmp_path / "videos" / "run"
    folder.mkdir(parents=True)
    (folder / "train-episode-27.gif").write_bytes(b"a film of the first leg")
    env = make_env("MiniQbert-v0", 0, 0, capture_video=True, run_name="run",
                   first_video_episode=27)()
    play(env, 1)
    env.close()
    assert (folder / "train-episode-27.gif").read_bytes() == b"a film of the first leg"
    with Image.open(folder / "train-episode-27-2.gif") as gif:
        assert gif.n_frames > 1


# -- every script, as a user runs it ------------------------------------------------------------


def user(script: str, *words: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(cwd), "LANG": "C.UTF-8"}
    return subprocess.run([str(BIN / "python"), str(ALGOS / f"{script}.py"), *words], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=300,
                          stdin=subprocess.DEVNULL)


TINY = {"compile_a2c": ("--compile-iterations", "5", "--compile-option-steps", "5")}


def test_the_scripts_that_film_are_found():
    assert {"rapl_a2c", "rapl_ppo", "compile_a2c"} <= set(FILMING)


@pytest.mark.parametrize("script", FILMING)
def test_capture_video_films_training_and_evaluation_and_writes_eval_json(script, tmp_path):
    # Issue 46: compile_a2c.py crashed after the whole run (the filmed evaluation called its
    # option policy with one argument): no eval.json, no GIF.
    proc = user(script, "--env-id", "MiniQbert-v0", "--total-timesteps", "2000",
                "--eval-episodes", "1", "--capture-video", "--run-dir", "runs",
                "--torch-threads", "1", *TINY.get(script, ()), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (run,) = (tmp_path / "runs").iterdir()
    assert (run / "eval.json").is_file()
    with Image.open(run / "videos" / "eval-episode-0.gif") as gif:
        assert gif.n_frames > 1
    films = sorted(p.name for p in (tmp_path / "videos" / run.name).iterdir())
    assert films[:2] == ["train-episode-0.gif", "train-episode-1.gif"]


def digests(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.iterdir()}


def test_a_bare_resume_of_a_filmed_run_keeps_the_first_legs_films(tmp_path):
    # Issue 46: the episode count restarted at 0 and the second leg overwrote
    # train-episode-0.gif, -1, -8; the flag is in the checkpoint, so a --resume without it did it
    # too (as here: the second leg is not given --capture-video).
    first = user("rapl_a2c", "--env-id", "MiniQbert-v0", "--total-timesteps", "2000",
                 "--eval-episodes", "0", "--capture-video", "--checkpoint-every", "1000",
                 "--run-dir", "runs", "--torch-threads", "1", cwd=tmp_path)
    assert first.returncode == 0, first.stderr[-3000:]
    (run,) = (tmp_path / "runs").iterdir()
    films = tmp_path / "videos" / run.name
    before = digests(films)
    counted = torch.load(run / "checkpoint.pt", weights_only=True)["video_episodes"]
    assert counted >= 2 and {"train-episode-0.gif", "train-episode-1.gif"} <= set(before)
    second = user("rapl_a2c", "--resume", str(run), "--total-timesteps", "8000", cwd=tmp_path)
    assert second.returncode == 0, second.stderr[-3000:]
    after = digests(films)
    assert {name: after[name] for name in before} == before  # not one overwritten
    new = set(after) - set(before)
    numbers = sorted(int(name.split("-")[2].split(".")[0]) for name in new)
    assert new and numbers[0] >= counted  # the second leg's films go on numbering
    assert torch.load(run / "checkpoint.pt", weights_only=True)["video_episodes"] > counted
