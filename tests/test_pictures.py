"""Pictures of routines (routine_gym/pictures.py, `routine-gym picture`) and captioned videos
(routine_gym/video.py, `--capture-video`): the data each picture is drawn from, checked against
hand-made demos and runs, and the command run as a user runs it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from one_line import assert_one_line_error
from PIL import Image

import routine_gym  # noqa: F401  (registers MiniQbert)
from routine_gym.cli import main
from routine_gym.demo import Demo, DemoRecorder
from routine_gym.library import RoutineLibrary
from routine_gym.mining import SequiturMiner
from routine_gym.pictures import (
    demo_timeline,
    draw_routine_picture,
    draw_routine_usage,
    routine_picture,
    routine_usage,
    top_routines,
)
from routine_gym.video import step_captions

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

REPO = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
MEANINGS = ["NOOP", "FIRE", "UP", "RIGHT", "LEFT", "DOWN"]  # MiniQbert's
NOOP, FIRE, UP, RIGHT, LEFT, DOWN = range(6)
#: MiniQbert's scripted expert's route over one level (11 jumps).
ROUTE = [DOWN, UP, RIGHT, RIGHT, RIGHT, LEFT, DOWN, LEFT, DOWN, LEFT, DOWN]


def user(*words: str | Path, cwd: Path, extra_env: dict[str, str] | None = None
         ) -> subprocess.CompletedProcess:
    """A command as a user's shell runs it: PATH with the venv first, HOME, nothing else."""
    env = {"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(cwd), "LANG": "C.UTF-8",
           **(extra_env or {})}
    words = [str(w) for w in words]
    words[0] = str(BIN / words[0])
    return subprocess.run(words, cwd=cwd, env=env, capture_output=True, text=True, timeout=300,
                          stdin=subprocess.DEVNULL)


def hand_made_demo() -> Demo:
    """Two episodes with known occurrences of (DOWN UP RIGHT) and (RIGHT DOWN UP), and an
    injected step in each; the second one splits a DOWN UP | RIGHT that is no occurrence."""
    actions = [DOWN, UP, RIGHT, NOOP, DOWN, UP, RIGHT, DOWN, UP, RIGHT,   # episode 0
               DOWN, UP, NOOP, RIGHT, DOWN, UP, RIGHT]                      # episode 1
    decided = [1, 1, 1, 0, 1, 1, 1, 1, 1, 1,
               1, 1, 0, 1, 1, 1, 1]
    ends = np.zeros(17, dtype=bool)
    ends[[9, 16]] = True
    return Demo(actions=np.array(actions), rewards=np.zeros(17), terminated=ends,
                truncated=np.zeros(17, dtype=bool), episode_lengths=np.array([10, 7]),
                decisions=np.array(decided, dtype=bool),
                meta={"env_id": "MiniQbert-v0", "seeds": [0, 1], "action_meanings": MEANINGS})


def test_timeline_marks_every_occurrence_and_the_injected_steps():
    timeline = demo_timeline(hand_made_demo(), [(DOWN, UP, RIGHT), (RIGHT, DOWN, UP)])
    # By hand: DOWN UP RIGHT at episode 0 steps 0, 4, 7 and episode 1 step 4 (demo step 14;
    # episode 1 starts at 10, and its DOWN UP NOOP RIGHT has an injected step inside);
    # RIGHT DOWN UP at episode 0 step 6 and episode 1 step 3 (demo step 13), not at episode 0
    # step 2 (RIGHT NOOP: the NOOP was injected).
    assert timeline.starts[0].tolist() == [0, 4, 7, 14]
    assert timeline.starts[1].tolist() == [6, 13]
    assert timeline.injected.tolist() == [3, 12]
    assert timeline.episode_starts.tolist() == [0, 10]
    assert timeline.routine_lengths == (3, 3) and timeline.num_steps == 17


def _recorded_miniqbert(observations: bool) -> Demo:
    """One MiniQbert game along the expert's route, RGB observations kept."""
    recorder = DemoRecorder(gym.make("MiniQbert-v0", obs_type="rgb"), record_observations=True)
    recorder.reset(seed=3)
    for action in [NOOP, *ROUTE, FIRE, *ROUTE, *ROUTE]:
        _, _, terminated, truncated, _ = recorder.step(action)
    assert terminated
    demo = recorder.demo()
    if observations:
        return demo
    return Demo(actions=demo.actions, rewards=demo.rewards, terminated=demo.terminated,
                truncated=demo.truncated, episode_lengths=demo.episode_lengths, meta=demo.meta)


@pytest.mark.parametrize("kept", [False, True], ids=["replayed", "observations"])
def test_each_film_is_the_demos_frames_at_the_routines_first_occurrence(kept):
    recorded = _recorded_miniqbert(observations=True)
    demo = _recorded_miniqbert(observations=kept)
    routines = [(RIGHT, RIGHT, RIGHT), (LEFT, DOWN, LEFT, DOWN), (NOOP, NOOP)]
    picture = routine_picture(demo, routines)
    first = [(0, 3), (0, 6), None]  # the NOOP at step 0 shifts the route by one
    for film, routine, where in zip(picture.films, routines, first, strict=True):
        assert film.routine == routine and film.occurrence == where
        if where is None:
            assert film.frames is None and film.frequency == 0
            continue
        assert film.frames.shape == (len(routine), 64, 64, 3)
        # Frame j is the screen before the routine's action j: the recorded observation.
        assert np.array_equal(film.frames, recorded.observations[where[1]: where[1] + len(routine)])
        assert film.captions == tuple(MEANINGS[a] for a in routine)
        assert film.name == " ".join(MEANINGS[a] for a in routine)
    # Once per level; LEFT DOWN LEFT DOWN twice per level, overlapping (steps 6 and 8).
    assert picture.films[0].frequency == 3 and picture.films[1].frequency == 6
    # Replayed only as far as the last frame needed (step 9), not the 35-step game.
    assert picture.replayed_steps == (0 if kept else 9)
    # The figure draws those frames, one axes per frame, captioned with the action.
    fig = draw_routine_picture(picture)
    titles = [ax.get_title() for ax in fig.get_axes() if ax.images]
    assert titles == ["RIGHT"] * 3 + ["LEFT", "DOWN", "LEFT", "DOWN"]
    drawn = [ax.images[0].get_array() for ax in fig.get_axes() if ax.images]
    assert np.array_equal(np.asarray(drawn[3]), recorded.observations[6])


def _spans(collection) -> list[tuple[int, int]]:
    """The `(start, length)` of each bar of a `broken_barh` collection."""
    xs = [path.vertices[:, 0] for path in collection.get_paths()]
    return sorted((round(x.min()), round(x.max() - x.min())) for x in xs)


def test_the_drawn_timeline_holds_the_occurrences_and_injected_steps():
    from routine_gym.pictures import Film, RoutinePicture

    demo = hand_made_demo()
    routines = [(DOWN, UP, RIGHT), (RIGHT, DOWN, UP)]
    timeline = demo_timeline(demo, routines)
    films = tuple(Film(index=k, routine=r, name="", frequency=int(timeline.starts[k].size),
                       occurrence=(0, int(timeline.starts[k][0])),
                       frames=np.zeros((3, 8, 8, 3), np.uint8), captions=("a", "b", "c"))
                  for k, r in enumerate(routines))
    picture = RoutinePicture(env_id="MiniQbert-v0", source="hand", score=0.0,
                             num_decisions=demo.num_decisions, films=films, timeline=timeline,
                             replayed_steps=0)
    ax = draw_routine_picture(picture).get_axes()[-1]
    bars = {c.get_gid(): _spans(c) for c in ax.collections if c.get_gid()}
    assert bars == {"routine 0": [(0, 3), (4, 3), (7, 3), (14, 3)],
                    "routine 1": [(6, 3), (13, 3)],
                    "injected": [(3, 1), (12, 1)]}
    assert [round(line.get_xdata()[0]) for line in ax.lines if line.get_linestyle() == "--"] \
        == [10]  # the second episode's start
    assert [t.get_text() for t in ax.get_yticklabels()] == [
        "routine 0 (f = 4)", "routine 1 (f = 2)", "injected (2)"]


@pytest.mark.parametrize("name", ["MinAtar-Breakout-v1", "MinAtar-Freeway-v1"])
def test_a_long_demo_is_replayed_only_to_its_first_occurrences(name):
    demo = Demo.load(REPO / "demos" / f"{name}.npz")
    picture = routine_picture(demo, SequiturMiner(num_routines=3).mine(demo))
    ends = [f.occurrence[1] + len(f.routine) - 1 for f in picture.films if f.occurrence]
    assert ends and picture.replayed_steps == max(ends) < len(demo) // 2
    for film in picture.films:
        if film.occurrence is not None:
            assert film.frames.shape == (len(film.routine), 160, 160, 3)
            assert film.frames.std() > 0  # a game screen, not a blank frame


def test_picture_of_a_demo_as_a_user_runs_it(tmp_path):
    proc = user("routine-gym", "picture", REPO / "demos" / "MiniQbert-v0.npz", "--out",
                "pics/miniqbert.png", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "routine 0: LEFT DOWN LEFT DOWN" in proc.stdout
    with Image.open(tmp_path / "pics" / "miniqbert.png") as image:
        assert image.format == "PNG"
        width, height = image.size
        pixels = np.asarray(image.convert("RGB"))
    assert 700 <= width <= 2000 and 500 <= height <= 3000, image.size
    # MiniQbert's blue cubes are in the film strips (the frames were drawn).
    blue = (pixels[..., 2] > 150) & (pixels[..., 0] < 100)
    assert blue.sum() > 1000


RENDERLESS = '''
import gymnasium as gym
import numpy as np


class Renderless(gym.Env):
    metadata = {"render_modes": ["ansi"]}

    def __init__(self, render_mode=None):
        self.render_mode = render_mode
        self.action_space = gym.spaces.Discrete(2)
        self.observation_space = gym.spaces.Box(0.0, 1.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.zeros(1, np.float32), {}

    def step(self, action):
        return np.zeros(1, np.float32), 0.0, False, False, {}

    def render(self):
        return "text"


gym.register("Renderless-v0", entry_point=Renderless)
'''


def test_an_env_that_cannot_render_rgb_is_a_one_line_error(tmp_path):
    (tmp_path / "renderless.py").write_text(RENDERLESS)
    Demo(actions=np.array([0, 1, 1] * 4), rewards=np.zeros(12), terminated=np.zeros(12, bool),
         truncated=np.zeros(12, bool), episode_lengths=np.array([12]),
         meta={"env_id": "renderless:Renderless-v0", "seeds": [0]}).save(tmp_path / "demo.npz")
    RoutineLibrary(routines=((0, 1, 1),)).save(tmp_path / "lib.json")
    proc = user("routine-gym", "picture", "demo.npz", "--routines", "lib.json", "--out", "p.png",
                cwd=tmp_path, extra_env={"PYTHONPATH": str(tmp_path)})
    assert_one_line_error(proc, "Renderless-v0", "cannot render RGB frames", "['ansi']",
                          prefix="routine-gym: error:")
    assert not (tmp_path / "p.png").exists()


def _run_folder(path: Path) -> Path:
    """A run's TensorBoard log as `rapl_a2c.py` writes it (`Counters`), with two updates, and
    its `routines.json`."""
    from routine_gym.plumbing.counters import Counters
    from routine_gym.plumbing.scalars import ScalarWriter

    writer = ScalarWriter(str(path))
    counts = Counters(writer, num_primitives=6, num_extended=2)
    counts.add(np.array([0, 2, 3, 4, 5, 6, 6, 7]), steps=12)  # 5 primitives, R0 twice, R1 once
    counts.log(global_step=100, decisions=8, updates=1)
    counts.add(np.array([6, 6]), steps=6)                   # R0 twice
    counts.log(global_step=200, decisions=10, updates=2)
    writer.close()
    RoutineLibrary(routines=((DOWN, DOWN, DOWN), (UP, RIGHT, UP)),
                   action_meanings=MEANINGS).save(path / "routines.json")
    return path


def test_usage_of_a_run_is_the_decisions_weighted_share_per_bin(tmp_path):
    run = _run_folder(tmp_path / "run")
    usage = routine_usage(run)  # two updates: two bins, one update each
    assert usage.steps.tolist() == [100.0, 200.0] and usage.bin_width == 100.0
    assert usage.primitive_share.tolist() == [0.625, 0.0]
    assert usage.shares.tolist() == [[0.25, 1.0], [0.125, 0.0]]
    assert usage.names == ("DOWN DOWN DOWN", "UP RIGHT UP")
    # The whole run: (5 + 0) / 10 primitives, (2 + 2) / 10 R0, 1 / 10 R1.
    assert usage.overall == (0.5, 0.4, 0.1)
    assert (usage.decisions, usage.primitive_steps) == (10, 200)
    one = routine_usage(run, bins=1)
    assert one.primitive_share.tolist() == [0.5] and one.shares.tolist() == [[0.4], [0.1]]
    legend = [t.get_text() for t in draw_routine_usage(usage).axes[0].get_legend().get_texts()]
    assert legend == ["routine 1: UP RIGHT UP (10.0 %)", "routine 0: DOWN DOWN DOWN (40.0 %)",
                      "primitive actions (50.0 % of all decisions)"]


def test_picture_of_a_run_folder_and_its_errors(tmp_path, capsys):
    run = _run_folder(tmp_path / "run")
    assert main(["picture", str(run), "--out", str(tmp_path / "usage.png")]) == 0
    assert "primitives 50.0%, DOWN DOWN DOWN 40.0%, UP RIGHT UP 10.0%" in capsys.readouterr().out
    with Image.open(tmp_path / "usage.png") as image:
        assert image.size == (800, 420)
    for argv, message in [
        ([str(run), "--routines", "lib.json"], "is a run folder"),
        ([str(tmp_path)], "holds no TensorBoard log"),
    ]:
        argv = ["picture", *argv, "--out", str(tmp_path / "x.png")]
        with pytest.raises(SystemExit) as excinfo:
            main(argv)
        assert excinfo.value.code == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err


def test_step_captions_name_the_routine_being_executed():
    # FIRE injected by a reset, routine 1 (3 steps) decided, a primitive, then routine 0 cut
    # short by the end of the episode after one step.
    captions = step_captions(
        actions=[FIRE, UP, RIGHT, UP, LEFT, NOOP, DOWN], decided=[0, 1, 1, 1, 1, 0, 1],
        choices=[7, LEFT, 6], num_actions=6, routines=[(DOWN, DOWN), (UP, RIGHT, UP)],
        action_meanings=MEANINGS)
    assert captions == ["injected: FIRE", "R1 UP RIGHT UP 1/3: UP", "R1 UP RIGHT UP 2/3: RIGHT",
                        "R1 UP RIGHT UP 3/3: UP", "LEFT", "injected: NOOP",
                        "R0 DOWN DOWN 1/2: DOWN"]


def test_capture_video_films_the_evaluation_with_routines_named(tmp_path):
    from routine_gym.plumbing.evaluation import evaluate_policy

    plan = iter([7, LEFT, 6, 6, 6, 6, 6, 6, 6, 6])  # R1, a primitive, then R0 until the end

    def policy(obs):
        return next(plan, 6)

    summary = evaluate_policy("MiniQbert-v0", policy, episodes=1, seed=0,
                              routines=[(DOWN, DOWN), (UP, RIGHT, UP)], max_steps=12,
                              video_folder=str(tmp_path / "videos"))
    with Image.open(tmp_path / "videos" / "eval-episode-0.gif") as gif:
        assert gif.n_frames == summary["lengths"][0] + 1  # a frame before each step, one after
        assert gif.size[0] == 320


def test_rapl_a2c_capture_video_films_training_and_evaluation_without_moviepy(tmp_path):
    proc = user("python", REPO / "algos" / "rapl_a2c.py", "--env-id", "MiniQbert-v0",
                "--total-timesteps", "300", "--num-envs", "2", "--eval-episodes", "1",
                "--capture-video", "--run-dir", "runs", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (run,) = (tmp_path / "runs").iterdir()
    with Image.open(run / "videos" / "eval-episode-0.gif") as gif:
        assert gif.n_frames > 1
    # Training env 0's first episode, on CleanRL's schedule, where CleanRL puts it.
    assert (tmp_path / "videos" / run.name / "train-episode-0.gif").is_file()


# -- a bounded number of routines (issue 46 case 8) --------------------------------------------


def test_top_routines_keeps_the_best_by_score_in_the_librarys_order():
    library = RoutineLibrary(routines=((0, 1), (1, 2), (2, 0), (0, 2)),
                             scores=(2.0, 5.0, 3.0, 5.0), frequencies=(1, 4, 2, 4))
    top = top_routines(library, 3)
    # 5.0, 5.0 and 3.0 are the best three; kept in the library's order, evidence with them.
    assert top.routines == ((1, 2), (2, 0), (0, 2)) and top.frequencies == (4, 2, 4)
    assert top_routines(library, 9) is library
    assert top_routines(RoutineLibrary(routines=((0, 1), (1, 2))), 1).routines == ((0, 1),)


def test_a_picture_of_a_large_library_draws_a_bounded_number_and_says_so(tmp_path):
    import time

    demo = REPO / "demos" / "MinAtar-SpaceInvaders-v1.npz"
    library = SequiturMiner(num_routines=100, alpha=1).mine(Demo.load(demo))
    assert len(library) > 100 // 2  # about a hundred routines (119 from 200 asked)
    library.save(tmp_path / "big.json")
    env = {"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(tmp_path)}
    start = time.monotonic()
    proc = subprocess.run([str(BIN / "routine-gym"), "picture", str(demo), "--routines",
                           "big.json", "--out", "big.png"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[-1] == (f"drew 12 of {len(library)} routines (the best by "
                                            "score); --max-routines to change")
    assert proc.stdout.count("  routine ") == 12
    assert (tmp_path / "big.png").is_file()
    assert time.monotonic() - start < 120  # > 180 s before, with every routine drawn
    proc = subprocess.run([str(BIN / "routine-gym"), "picture", str(demo), "--routines",
                           "big.json", "--out", "big.png", "--max-routines", "0"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert_one_line_error(proc, "--max-routines needs to be in [1, 1000], actual value: 0")
