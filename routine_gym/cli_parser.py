"""The grammar of the `routine-gym` command line: its commands, their arguments and help.

One function per command adds its parser; `routine_gym.cli.build_parser` binds each command to
the function that runs it.
"""

from __future__ import annotations

import argparse

from routine_gym.mining import PROPOSER_NAMES

__all__ = ["build_parsers"]


def build_parsers() -> tuple[argparse.ArgumentParser, dict[str, argparse.ArgumentParser]]:
    """The `routine-gym` parser, and the parser of each runnable command by name (`mine`, ...,
    `experiment run`), for the caller to bind to the function that runs it."""
    parser = argparse.ArgumentParser(
        prog="routine-gym",
        description="Mine action routines from a demonstration, inspect them, and record, "
        "replay or export demonstrations. A demo is a .npz file or a local Minari dataset "
        "(minari:DATASET_ID). Errors are one line with exit code 2; --debug (anywhere on the "
        "command line) or ROUTINE_GYM_DEBUG=1 shows their traceback.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    return parser, {
        "mine": _add_mine(sub),
        "show": _add_show(sub),
        "show-demos": _add_show_demos(sub),
        "picture": _add_picture(sub),
        "replay": _add_replay(sub),
        "upgrade": _add_upgrade(sub),
        "export": _add_export(sub),
        "record": _add_record(sub),
        "play": _add_play(sub),
        **_add_experiment(sub),
    }


def _add_mine(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """`routine-gym mine DEMO`: mine a routine library and print it."""
    p = sub.add_parser("mine", help="mine a routine library from a demo and print it",
                       description="Mine the top-K routines of a demo (SPEC §2) and print them "
                       "with action names, scores and frequencies.")
    p.add_argument("demo", help="demo file (.npz) written by routine-gym, or a local Minari "
                   "dataset as minari:DATASET_ID")
    p.add_argument("--num-routines", "-k", type=int, default=3, help="K, routines to keep (3)")
    p.add_argument("--length-weight", type=float, default=0.1,
                   help="λ_length in the score f + λ·len (0.1)")
    p.add_argument("--alpha", type=int, default=2,
                   help="prune candidates within this Levenshtein distance of an accepted one (2)")
    p.add_argument("--proposer", default="full",
                   choices=PROPOSER_NAMES,
                   help="full = Sequitur (the paper's model); bpe = byte-pair encoding (merge the "
                   "most frequent pair of actions until none occurs twice); the others are the "
                   "paper's ablations")
    p.add_argument("--seed", type=int, default=0, help="seed of the random ablation proposers")
    p.add_argument("--keep-near-primitives", action="store_true",
                   help="do not count primitives as accepted (keeps length-2 routines at α=2)")
    p.add_argument("--max-routine-length", type=int, default=64, help="longest routine (64)")
    p.add_argument("--selection", default="paper", metavar="{paper,authors}",
                   help="paper: score f + λ·len, best first (default); authors: the authors' "
                   "released code, score f / mean f, containment pruning, rule order (SPEC §5b)")
    p.add_argument("--out", "-o", help="save the library as JSON here")
    return p


def _add_show(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """`routine-gym show PATH`: print a routine library or a demo."""
    p = sub.add_parser("show", help="print a routine library (.json) or a demo (.npz)")
    p.add_argument("path", help="a routine library JSON, a demo .npz, or a local Minari dataset "
                   "as minari:DATASET_ID")
    p.add_argument("--head", type=int, default=20, help="demo actions to print (20)")
    return p


def _add_show_demos(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """`routine-gym show-demos`: the shipped demos and their routines."""
    p = sub.add_parser("show-demos", help="list the shipped demos with their mined routines",
                       description="List every demo in demos/ (or --dir): env, score, length, "
                       "source, and the routines mined from it with action names.")
    p.add_argument("--dir", default=None, help="demo folder (the shipped demos/)")
    p.add_argument("--num-routines", "-k", type=int, default=3, help="K, routines to mine (3)")
    return p


def _add_picture(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """`routine-gym picture DEMO|RUN_DIR --out OUT.png`: pictures of routines."""
    p = sub.add_parser("picture", help="draw a demo's routines (film strips and timeline) or a "
                       "run's routine usage as a PNG",
                       description="Given a demo: for each routine, a film strip of the frames "
                       "of its first occurrence in the demo, each captioned with its action, "
                       "and a timeline of the demo marking every occurrence and the injected "
                       "steps; a demo without RGB observations is replayed from its seed as "
                       "far as needed (its env must render rgb_array). The routines are mined "
                       "from the demo as `mine` does, or read from --routines. Given a run "
                       "folder of a script in algos/: the share of the decisions that chose "
                       "each routine and the primitive actions against agent steps, from its "
                       "TensorBoard log (counters/primitive_share, counters/share_k).")
    p.add_argument("source", help="a demo file (.npz), a local Minari dataset as "
                   "minari:DATASET_ID, or a run folder (with TensorBoard events)")
    p.add_argument("--out", "-o", required=True, help="the PNG to write")
    p.add_argument("--routines", default=None, metavar="LIBRARY.json",
                   help="a demo's routines from this library (`mine --out`), instead of mining")
    p.add_argument("--num-routines", "-k", type=int, default=3,
                   help="K, routines to mine from a demo (3)")
    p.add_argument("--max-routines", type=int, default=12,
                   help="draw at most this many of a demo's routines, the best by score (12): "
                   "each is a film strip, and a picture of hundreds takes minutes")
    return p


def _add_replay(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """`routine-gym replay DEMO`: replay a demo from its seeds and verify it."""
    p = sub.add_parser("replay", help="replay a demo from its seed and verify it",
                       description="Re-run the demo's actions in its env from its seed and "
                       "check rewards, terminations and length match. Exit code 1 on mismatch.")
    p.add_argument("demo", help="demo file (.npz), or a local Minari dataset as "
                   "minari:DATASET_ID")
    p.add_argument("--episode", type=int, default=None, help="replay only this episode")
    return p


def _add_upgrade(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """`routine-gym upgrade DEMO`: rewrite a version-1 demo as version 2."""
    p = sub.add_parser("upgrade", help="rewrite a version-1 demo as version 2",
                       description="Replay a version-1 demo through the preprocessing it was "
                       "recorded under and mark which steps the demonstrator decided and which "
                       "the preprocessing injected (no-op start, FIRE, served lives). Refuses "
                       "when the replay diverges; nothing is written then.")
    p.add_argument("demo", help="demo file (.npz), format version 1")
    p.add_argument("--out", "-o", default=None, help="write here (default: replace DEMO)")
    p.add_argument("--preprocessing", default="auto",
                   help="the stack it was recorded under: agent (the evaluation view that "
                   "rapl_a2c.py --record-demo uses), agent-0.1 (Atari, without served lives), "
                   "raw (CLI record and play: every step a decision), or auto: the first of "
                   "these that replays exactly (auto)")
    return p


def _add_export(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """`routine-gym export DEMO --minari DATASET_ID`: a demo as a Minari dataset."""
    p = sub.add_parser("export", help="write a demo as a local Minari dataset",
                       description="Write the demo's episodes as a Minari dataset in the local "
                       "Minari folder (MINARI_DATASETS_PATH, else ~/.minari/datasets; nothing is "
                       "uploaded): observations (replayed from the seeds when the demo keeps "
                       "none), actions, rewards, flags, seeds, the decisions mask as "
                       "infos['decision'], the env spec, and the demo's meta under 'routine_gym'. "
                       "Arrow storage, image frames as PNG (lossless). Needs "
                       "`pip install routine-gym[minari]`. Read it back anywhere a demo is "
                       "taken as minari:DATASET_ID.")
    p.add_argument("demo", help="demo file (.npz)")
    p.add_argument("--minari", required=True, metavar="DATASET_ID",
                   help="the new dataset's id, (namespace/)name-vVERSION, e.g. "
                   "routine-gym/qbert-expert-v0; it must not exist yet")
    return p


def _add_record(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """`routine-gym record ENV_ID`: record an agent's demo."""
    p = sub.add_parser("record", help="record an agent's demo (best of N episodes)",
                       description="Run a policy for N episodes and save the best one.")
    p.add_argument("env_id", help="a Gymnasium env id, e.g. MiniQbert-v0 or ALE/Qbert-v5")
    p.add_argument("--out", "-o", required=True, help="demo file to write (.npz)")
    p.add_argument("--policy", default="random",
                   help="random, expert (MiniQbert's scripted expert) or module:function "
                   "taking an observation and returning an action (random)")
    p.add_argument("--expert-noise", type=float, default=0.0,
                   help="with --policy expert: probability of a uniformly random action (0)")
    p.add_argument("--episodes", "-n", type=int, default=10, help="episodes to run (10)")
    p.add_argument("--keep", choices=["best", "all"], default="best",
                   help="save the best episode or all of them (best)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first episode (0)")
    p.add_argument("--max-steps", type=int, default=None, help="cut episodes at this length")
    _add_recording_options(p)
    return p


def _add_recording_options(p: argparse.ArgumentParser) -> None:
    """What `record` and `play` share: the observations kept and `gym.make`'s arguments."""
    p.add_argument("--observations", action="store_true", help="store observations too")
    p.add_argument("--env-kwarg", action="append", metavar="KEY=VALUE",
                   help="keyword argument for gym.make (repeatable)")


def _add_play(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """`routine-gym play ENV_ID`: record a person's demo at the keyboard."""
    p = sub.add_parser("play", help="play an env with the keyboard and save the demo",
                       description="Human demonstration through gymnasium.utils.play. Needs a "
                       "display. Close the window or press Escape to stop.")
    p.add_argument("env_id", help="a Gymnasium env id with keyboard controls, e.g. ALE/Qbert-v5")
    p.add_argument("--out", "-o", required=True, help="demo file to write (.npz)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first episode (0)")
    p.add_argument("--episodes", "-n", type=int, default=1, help="episodes to play (1)")
    p.add_argument("--fps", type=int, default=None, help="frames per second (env default)")
    p.add_argument("--zoom", type=float, default=None, help="window zoom factor")
    _add_recording_options(p)
    return p


def _add_experiment(sub: argparse._SubParsersAction) -> dict[str, argparse.ArgumentParser]:
    """`routine-gym experiment list|run|report`: the paper's experiments."""
    p = sub.add_parser("experiment", help="the paper's experiments and ours: list, run, report",
                       description="The paper's six experiments (SPEC §8), the fair protocol's "
                       "tuning, the diagnosis and equal-frames as sweeps of runs of the scripts "
                       "in algos/: resumable, local or on a Ray cluster.")
    esub = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    listing = esub.add_parser("list",
                              help="the experiments, their budgets and how many runs each has")
    q = esub.add_parser("run", help="run an experiment (finished runs are skipped, killed ones "
                        "resume)")
    q.add_argument("name", help="an experiment `experiment list` shows (tune, rl, diagnosis, "
                   "equal-frames, ...), or all")
    q.add_argument("--budget", required=True,
                   help="a budget `experiment list` shows and describes (smoke, cpu, paper, long, "
                   "smoke-fair, fair, fair-long)")
    q.add_argument("--out", required=True, help="the sweep folder (the same one to resume)")
    q.add_argument("--jobs", type=int, default=1,
                   help="runs at a time (local), or the local Ray instance's CPUs (1)")
    q.add_argument("--backend", default="local", help="local (default) or ray")
    q.add_argument("--address", default=None,
                   help="HOST:PORT of a Ray cluster to join (default: start a local one)")
    q.add_argument("--seeds", type=int, nargs="+", default=None,
                   help="only these seeds (and the runs of other seeds they need)")
    q.add_argument("--envs", nargs="+", default=None, help="only these games")
    q.add_argument("--cuda", action="store_true", help="runs use CUDA (Ray: one GPU per run)")
    q.add_argument("--cpus-per-run", type=int, default=1,
                   help="CPUs a Ray task asks for, ≥ 1 (1)")
    q.add_argument("--track", action="store_true",
                   help="every run also logs to Weights & Biases (pip install "
                   "'routine-gym[wandb]'); runs keep their keys, so a sweep resumes either way")
    q.add_argument("--wandb-project-name", default=None,
                   help="the W&B project of --track (routine-gym)")
    q.add_argument("--wandb-entity", default=None,
                   help="the W&B entity (team) of --track (your default entity)")
    run = q
    q = esub.add_parser("report", help="figures (PNG + CSV) and report.md of a sweep folder",
                        description="Write OUT/report/ from the runs finished in OUT. It only "
                        "reads the sweep, so it may run while a sweep runs there (the runs in "
                        "flight count as missing).")
    q.add_argument("out", help="the sweep folder of `experiment run`")
    q.add_argument("--out", dest="report_dir", default=None, metavar="FOLDER",
                   help="where the report goes (default: OUT/report); made when missing")
    q.add_argument("--beside", default=None, metavar="OTHER_SWEEP",
                   help="also compare the rl experiment with OTHER_SWEEP's at another budget "
                   "(e.g. the cpu budget's 10^6 steps beside the long budget's 10^7; which is "
                   "which comes from the runs' steps): budgets_fig2, budgets_curves and "
                   "budgets_routines (PNG + CSV) and a section of report.md")
    return {"experiment list": listing, "experiment run": run, "experiment report": q}
