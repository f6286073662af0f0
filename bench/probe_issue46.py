"""A probe of issue 46's surfaces as a user meets them: about 200 bad or unusual commands, each
run in a fresh process with a minimal environment (PATH with the venv's bin first, HOME, LANG),
in a folder of its own, with tiny budgets, and each outcome classified:

    GOOD       exit code 0 with the expected output, or a one-line error (one non-empty line on
               stderr, no traceback) with exit code 1, 2 or 3 (a run that diverged)
    TRACEBACK  a Python traceback on stderr
    WRONG      exit code 0 where it should fail, another exit code (a crash), an error that is
               not one line, a file written where it must not be (a file named `minari:X`, a run
               folder left by a refused run, anything outside the case's folder), a kept file
               changed or lost, a hang past the case's timeout, or a wrong output

The surfaces: pictures, Minari (`minari:ID` as a source and as an output, `export`), `--track`,
the modes and flags of rapl_a2c.py and rapl_ppo.py, BPE, `--capture-video`, the compiled cores
(`ROUTINE_GYM_NATIVE`), `--resume` (missing, corrupt, locked, twice at once), the 13 numbered
cases of issue 46, and the flags added since (`--seed-stride`, `--rollout-unit`,
`--scalars-every`, the tune experiment at `--budget smoke-fair`, `experiment report --out`).

    nice .venv/bin/python bench/probe_issue46.py                 # every case, 3 at a time
    nice .venv/bin/python bench/probe_issue46.py -k resume -v    # the cases whose name has it

Not collected by pytest (its name does not start with `test_`); the fixes it found are pinned
by tests/test_probe_fixes.py. Prints one line per case that is not GOOD, then the counts, and
writes every outcome to `--json` when given.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
ALGOS = REPO / "algos"
DEMOS = REPO / "demos"
MQ = DEMOS / "MiniQbert-v0.npz"
BREAKOUT = DEMOS / "MinAtar-Breakout-v1.npz"
TINY = ["--env-id", "MiniQbert-v0", "--total-timesteps", "500", "--eval-episodes", "1",
        "--num-envs", "2"]
#: A check of a finished case: None when its output is right, else what is wrong.
Check = Callable[[Path, subprocess.CompletedProcess], "str | None"]


@dataclass
class Case:
    """One command of the probe. `words` start with `rg` (the venv's routine-gym), `py` (its
    python) or a script's name in algos/ (`rapl_a2c`)."""

    name: str
    words: list[str]
    expect: str = "error"  # error | ok | either (a one-line error or rc 0, never a traceback)
    check: Check | None = None
    env: dict[str, str] = field(default_factory=dict)
    setup: Callable[[Path], None] | None = None
    keep: tuple[str, ...] = ()  # files (relative to the case's cwd) that must stay unchanged
    timeout: float = 150
    twice: bool = False  # run the command twice at once: one must finish, the other refuse
    rc: tuple[int, ...] = (1, 2)  # the exit codes of an expected error


@dataclass
class Outcome:
    """What a case did and how it is classified."""

    name: str
    verdict: str
    reason: str
    rc: int | None
    seconds: float
    stderr_tail: str


# -- the shared inputs, made once -------------------------------------------------------------


class Shared:
    """Inputs the cases copy: demos, libraries, a Minari dataset, finished runs, a sweep."""

    def __init__(self, root: Path, bin_dir: Path) -> None:
        self.root = root
        self.bin = bin_dir
        self.minari = root / "minari"

    def env(self, home: Path, extra: dict[str, str] | None = None) -> dict[str, str]:
        env = {"PATH": f"{self.bin}:/usr/bin:/bin", "HOME": str(home), "LANG": "C.UTF-8",
               "MINARI_DATASETS_PATH": str(self.minari)}
        env.update(extra or {})
        return {k: v for k, v in env.items() if v is not None}

    def argv(self, words: list[str]) -> list[str]:
        head, rest = words[0], [str(w) for w in words[1:]]
        if head == "rg":
            return [str(self.bin / "routine-gym"), *rest]
        if head == "py":
            return [str(self.bin / "python"), *rest]
        return [str(self.bin / "python"), str(ALGOS / f"{head}.py"), *rest]

    def run(self, words: list[str], cwd: Path, timeout: float = 300,
            env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
        return subprocess.run(self.argv(words), cwd=cwd, env=self.env(cwd, env),
                              capture_output=True, text=True, timeout=timeout,
                              stdin=subprocess.DEVNULL)

    def must(self, words: list[str], cwd: Path, **kw) -> subprocess.CompletedProcess:
        proc = self.run(words, cwd, **kw)
        if proc.returncode != 0:
            raise SystemExit(f"probe set-up failed: {words}\n{proc.stderr[-3000:]}")
        return proc

    def make(self) -> None:
        """Everything the cases share (about two minutes on a loaded 2-core machine)."""
        r = self.root
        shutil.copy(MQ, r / "mq.npz")
        shutil.copy(BREAKOUT, r / "breakout.npz")
        (r / "garbage.npz").write_bytes(b"PK\x03\x04 this is not a zip file at all" * 10)
        (r / "garbage.json").write_text("{not json")
        self.must(["rg", "mine", "mq.npz", "--out", "lib.json"], r)
        self.must(["rg", "mine", "breakout.npz", "--out", "breakout-lib.json"], r)
        self.must(["rg", "export", "mq.npz", "--minari", "rg/mq-v0"], r)
        self.must(["rg", "export", "mq.npz", "--minari", "rg/h5-v0"], r)
        meta = self.minari / "rg" / "h5-v0" / "data" / "metadata.json"
        data = json.loads(meta.read_text())
        data["data_format"] = "hdf5"  # what Minari's default format says (h5py absent here)
        meta.write_text(json.dumps(data))
        # A periodic demo (issue 46 case 4): 40,000 actions repeating 8, on MiniQbert.
        self.must(["py", "-c", (
            "import numpy as np, routine_gym\n"
            "from routine_gym.demo import Demo\n"
            "n = 40000\n"
            "a = np.tile([1, 1, 2, 0, 2, 2, 1, 0], n // 8)\n"
            "Demo(actions=a, rewards=np.zeros(n), terminated=np.arange(n) == n - 1,\n"
            "     truncated=np.zeros(n, bool), episode_lengths=np.array([n]),\n"
            "     meta={'env_id': 'MiniQbert-v0', 'seeds': [0]}).save('rep.npz',\n"
            "     include_observations=False)\n")], r)
        # A library of many routines (case 8): random play mined with K = 200, α = 1.
        self.must(["rg", "record", "MiniQbert-v0", "--episodes", "20", "--keep", "all",
                   "--out", "random.npz"], r)
        self.must(["rg", "mine", "random.npz", "-k", "200", "--alpha", "1", "--out",
                   "big-lib.json"], r)
        # Finished runs with checkpoints: rapl_a2c, rapl_ppo, and rapl_a2c filmed (case 2).
        for name, script, extra in (("a2c", "rapl_a2c", []), ("ppo", "rapl_ppo", []),
                                    ("video", "rapl_a2c", ["--capture-video"])):
            self.must([script, *TINY, "--total-timesteps", "400", "--checkpoint-every", "200",
                       "--run-dir", f"runs-{name}", *extra], r)
            (folder,) = (r / f"runs-{name}").iterdir()
            folder.rename(r / f"run-{name}")
            (r / f"runs-{name}").rmdir()
        # A checkpoint whose saved settings ask for 10^7 envs (case 5, from a checkpoint).
        self.must(["py", "-c", (
            "import json, torch\n"
            "c = torch.load('run-a2c/checkpoint.pt', weights_only=True)\n"
            "a = json.loads(c['args'])\n"
            "a['num_envs'] = 10 ** 7\n"
            "c['args'] = json.dumps(a)\n"
            "torch.save(c, 'huge-envs.pt')\n")], r)
        data = (r / "run-a2c" / "checkpoint.pt").read_bytes()
        (r / "truncated.pt").write_bytes(data[: len(data) // 2])
        # A finished sweep to report on.
        self.must(["rg", "experiment", "run", "rl", "--budget", "smoke", "--out", "sweep"], r,
                  timeout=600)


# -- checks -------------------------------------------------------------------------------------


def exists(*paths: str) -> Check:
    """Each path (a glob, relative to the case's cwd) matches something."""
    def check(cwd: Path, proc: subprocess.CompletedProcess) -> str | None:
        for pattern in paths:
            if not list(cwd.glob(pattern)):
                return f"{pattern} missing"
        return None
    return check


def absent(*paths: str) -> Check:
    """No path matches any of the globs."""
    def check(cwd: Path, proc: subprocess.CompletedProcess) -> str | None:
        for pattern in paths:
            found = list(cwd.glob(pattern))
            if found:
                return f"{found[0].relative_to(cwd)} written"
        return None
    return check


def stdout_has(*texts: str) -> Check:
    def check(cwd: Path, proc: subprocess.CompletedProcess) -> str | None:
        for text in texts:
            if text not in proc.stdout:
                return f"stdout lacks {text!r}"
        return None
    return check


def both(*checks: Check) -> Check:
    def check(cwd: Path, proc: subprocess.CompletedProcess) -> str | None:
        for one in checks:
            why = one(cwd, proc)
            if why:
                return why
        return None
    return check


def eval_has(*keys: str, folder: str = "runs/*") -> Check:
    """The run's eval.json exists and holds every key."""
    def check(cwd: Path, proc: subprocess.CompletedProcess) -> str | None:
        found = list(cwd.glob(f"{folder}/eval.json"))
        if not found:
            return f"no {folder}/eval.json"
        data = json.loads(found[0].read_text())
        missing = [k for k in keys if k not in data]
        return f"eval.json lacks {missing}" if missing else None
    return check


def is_png(path: str) -> Check:
    def check(cwd: Path, proc: subprocess.CompletedProcess) -> str | None:
        p = cwd / path
        if not p.is_file() or p.read_bytes()[:8] != b"\x89PNG\r\n\x1a\n":
            return f"{path} is not a PNG"
        return None
    return check


def smaller_than(pattern: str, limit: int) -> Check:
    def check(cwd: Path, proc: subprocess.CompletedProcess) -> str | None:
        found = list(cwd.glob(pattern))
        if not found:
            return f"{pattern} missing"
        big = [p for p in found if p.stat().st_size > limit]
        return f"{big[0].name} is {big[0].stat().st_size} bytes" if big else None
    return check


def copy(*names: str, to: str | None = None) -> Callable[[Path], None]:
    """Set-up: copy shared inputs into the case's cwd (a folder whole)."""
    def setup(cwd: Path) -> None:
        for name in names:
            src = SHARED.root / name
            dst = cwd / (to or name)
            if src.is_dir():
                shutil.copytree(src, dst)
            else:
                shutil.copy(src, dst)
    return setup


def chain(*setups: Callable[[Path], None]) -> Callable[[Path], None]:
    def setup(cwd: Path) -> None:
        for one in setups:
            one(cwd)
    return setup


def mkdir(*names: str) -> Callable[[Path], None]:
    def setup(cwd: Path) -> None:
        for name in names:
            (cwd / name).mkdir(parents=True, exist_ok=True)
    return setup


def write(name: str, text: str) -> Callable[[Path], None]:
    def setup(cwd: Path) -> None:
        (cwd / name).write_text(text)
    return setup


# -- the cases ----------------------------------------------------------------------------------


def cases() -> list[Case]:
    c: list[Case] = []

    def add(name, words, expect="error", **kw):
        c.append(Case(name, words, expect, **kw))

    mq = copy("mq.npz")
    lib = copy("lib.json")
    # --- pictures
    add("picture/demo", ["rg", "picture", "mq.npz", "--out", "p.png"], "ok", setup=mq,
        check=is_png("p.png"))
    add("picture/minari", ["rg", "picture", "minari:rg/mq-v0", "--out", "p.png"], "ok",
        check=is_png("p.png"))
    add("picture/run-folder", ["rg", "picture", "run-a2c", "--out", "r.png"], "ok",
        setup=copy("run-a2c"), check=is_png("r.png"))
    add("picture/routines", ["rg", "picture", "mq.npz", "--routines", "lib.json", "--out",
                             "p.png"], "ok", setup=chain(mq, lib), check=is_png("p.png"))
    add("picture/case8-big-library", ["rg", "picture", "random.npz", "--routines",
                                      "big-lib.json", "--out", "p.png"], "ok",
        setup=copy("random.npz", "big-lib.json"), timeout=120, check=is_png("p.png"))
    add("picture/max-routines-1", ["rg", "picture", "mq.npz", "--max-routines", "1", "--out",
                                   "p.png"], "ok", setup=mq, check=is_png("p.png"))
    add("picture/max-routines-huge", ["rg", "picture", "mq.npz", "--max-routines",
                                      str(10 ** 12), "--out", "p.png"], "either", setup=mq)
    for bad in ("0", "-1", "x"):
        add(f"picture/max-routines={bad}", ["rg", "picture", "mq.npz", "--max-routines", bad,
                                            "--out", "p.png"], setup=mq, check=absent("p.png"))
    for bad in ("0", "-3", str(10 ** 12)):
        add(f"picture/num-routines={bad}", ["rg", "picture", "mq.npz", "-k", bad, "--out",
                                            "p.png"],
            "error" if bad != str(10 ** 12) else "either", setup=mq)
    for out in ("p.jpg", "minari:x-v0", "", "dir/", "mq.npz"):
        add(f"picture/out={out!r}", ["rg", "picture", "mq.npz", "--out", out], setup=mq,
            keep=("mq.npz",), check=absent("p.jpg", "dir"))
    add("picture/out-is-folder", ["rg", "picture", "mq.npz", "--out", "d"],
        setup=chain(mq, mkdir("d")))
    add("picture/out-under-a-file", ["rg", "picture", "mq.npz", "--out", "f.txt/p.png"],
        setup=chain(mq, write("f.txt", "x")), keep=("f.txt",))
    add("picture/missing-source", ["rg", "picture", "nope.npz", "--out", "p.png"])
    add("picture/garbage-source", ["rg", "picture", "garbage.npz", "--out", "p.png"],
        setup=copy("garbage.npz"))
    add("picture/json-source", ["rg", "picture", "lib.json", "--out", "p.png"], setup=lib)
    add("picture/empty-folder", ["rg", "picture", "empty", "--out", "p.png"],
        setup=mkdir("empty"))
    add("picture/routines-missing", ["rg", "picture", "mq.npz", "--routines", "no.json",
                                     "--out", "p.png"], setup=mq)
    add("picture/routines-garbage", ["rg", "picture", "mq.npz", "--routines", "garbage.json",
                                     "--out", "p.png"], setup=chain(mq, copy("garbage.json")))
    add("picture/routines-other-env", ["rg", "picture", "mq.npz", "--routines",
                                       "breakout-lib.json", "--out", "p.png"], "either",
        setup=chain(mq, copy("breakout-lib.json")))
    add("picture/minari-missing", ["rg", "picture", "minari:rg/nope-v0", "--out", "p.png"])
    add("picture/minari-hdf5", ["rg", "picture", "minari:rg/h5-v0", "--out", "p.png"])
    add("picture/run-without-events", ["rg", "picture", "run", "--out", "p.png"],
        setup=chain(mkdir("run"), write("run/eval.json", "{}")))

    # --- Minari as a source
    add("minari/mine", ["rg", "mine", "minari:rg/mq-v0"], "ok", check=stdout_has("[0] len="))
    add("minari/show", ["rg", "show", "minari:rg/mq-v0"], "ok")
    add("minari/replay", ["rg", "replay", "minari:rg/mq-v0"], "ok",
        check=stdout_has("matches the recording"))
    for ident in ("rg/nope-v0", "", "Bad Id", "../../etc-v0", "a" * 300 + "-v0"):
        add(f"minari/mine-id={ident[:30]!r}", ["rg", "mine", f"minari:{ident}"])
    add("minari/hdf5-mine", ["rg", "mine", "minari:rg/h5-v0"])
    add("minari/hdf5-rapl_a2c", ["rapl_a2c", *TINY, "--demo", "minari:rg/h5-v0"],
        check=absent("runs/*"))
    add("minari/rapl_a2c-demo", ["rapl_a2c", *TINY, "--demo", "minari:rg/mq-v0"], "ok",
        check=eval_has("mean_alignment"))
    add("minari/rapl_a2c-demo-missing", ["rapl_a2c", *TINY, "--demo", "minari:rg/no-v0"],
        check=absent("runs/*"))
    add("minari/rapl_a2c-demo-other-env", ["rapl_a2c", *TINY, "--env-id",
                                           "MinAtar/Breakout-v1", "--demo", "minari:rg/mq-v0"],
        check=absent("runs/*"))
    add("minari/rapl_ppo-demo", ["rapl_ppo", *TINY, "--demo", "minari:rg/mq-v0"], "ok",
        check=eval_has("mean_alignment"))
    # --- Minari as an output (case 3) and export (case 10)
    for words in (["rg", "mine", "mq.npz", "--out", "minari:rg/out-v0"],
                  ["rg", "mine", "mq.npz", "--out", "minari:"],
                  ["rg", "upgrade", "mq.npz", "--out", "minari:up-v0"],
                  ["rg", "record", "MiniQbert-v0", "-n", "1", "--out", "minari:rec-v0"],
                  ["rapl_a2c", *TINY, "--record-demo", "minari:rd-v0"],
                  ["rapl_ppo", *TINY, "--record-demo", "minari:rd-v0"],
                  ["rapl_a2c", *TINY, "--run-dir", "minari:runs"],
                  ["rapl_sqil", "--env-id", "MiniQbert-v0", "--total-timesteps", "500",
                   "--record-demo", "minari:rd-v0"],
                  ["rg", "experiment", "run", "rl", "--budget", "smoke", "--out",
                   "minari:sweep-v0"],
                  ["rg", "experiment", "report", "sweep", "--out", "minari:rep-v0"]):
        add(f"case3/{words[0]} {words[1]} {words[-2]} {words[-1]}", words,
            setup=chain(mq, copy("sweep")), keep=("mq.npz",), check=absent("runs/*"))
    add("export/ok", ["rg", "export", "mq.npz", "--minari", "rg/new-v0"], "ok", setup=mq,
        env={"MINARI_DATASETS_PATH": "m"},
        check=exists("m/rg/new-v0/data/metadata.json"))
    for ident in ("rg/mq-v0", "rg/mq-v0/sub-v0", "rg", "", "minari:z-v0", "/abs-v0",
                  "../up-v0"):
        add(f"export/id={ident!r}", ["rg", "export", "mq.npz", "--minari", ident], setup=mq)
    add("export/missing-demo", ["rg", "export", "no.npz", "--minari", "rg/e1-v0"])
    add("export/garbage-demo", ["rg", "export", "garbage.npz", "--minari", "rg/e2-v0"],
        setup=copy("garbage.npz"))
    add("export/datasets-path-is-a-file", ["rg", "export", "mq.npz", "--minari", "e3-v0"],
        setup=chain(mq, write("f", "x")), env={"MINARI_DATASETS_PATH": "f"}, keep=("f",))
    # As root a read-only folder is written all the same: then rc 0 is right.
    add("export/datasets-path-read-only", ["rg", "export", "mq.npz", "--minari", "e4-v0"],
        "error" if os.geteuid() else "either",
        setup=chain(mq, mkdir("ro"), lambda cwd: (cwd / "ro").chmod(0o555)),
        env={"MINARI_DATASETS_PATH": "ro"})
    add("export/nested-in-new-root", ["rg", "export", "mq.npz", "--minari", "a/b/c-v0"],
        "either", setup=mq, env={"MINARI_DATASETS_PATH": "m"})
    add("show-demos/dir-minari", ["rg", "show-demos", "--dir", "minari:x-v0"])

    # --- --track
    off = {"WANDB_MODE": "offline"}
    for script in ("rapl_a2c", "rapl_ppo", "compile_a2c", "option_critic", "rapl_sqil"):
        add(f"track/{script}-bad-project", [script, *TINY, "--track", "--wandb-project-name",
                                            "a/b"], env=off, check=absent("runs/*"))
    for project in ("x#y", "c:d"):
        add(f"track/project={project}", ["rapl_a2c", *TINY, "--track",
                                         "--wandb-project-name", project], env=off,
            check=absent("runs/*"))
    # Offline, W&B takes any entity (it is checked by the server): rc 0 is right too.
    add("track/entity-bad", ["rapl_a2c", *TINY, "--track", "--wandb-entity", "a/b"], "either",
        env=off)
    add("track/no-key", ["rapl_a2c", *TINY, "--track"], check=absent("runs/*"))
    add("track/offline-ok", ["rapl_a2c", *TINY, "--track"], "ok", env=off,
        check=both(exists("runs/*/eval.json"),
                   exists("wandb")))
    add("track/sweep-bad-project", ["rg", "experiment", "run", "rl", "--budget", "smoke",
                                    "--out", "sw", "--track", "--wandb-project-name", "a/b"],
        env=off, check=absent("sw/runs/*"))
    add("track/sweep-no-key", ["rg", "experiment", "run", "rl", "--budget", "smoke", "--out",
                               "sw", "--track"], check=absent("sw/runs/*"))
    add("track/wandb-mode-garbage", ["rapl_a2c", *TINY, "--track"], "either",
        env={"WANDB_MODE": "garbage"})
    add("track/project-without-track", ["rapl_a2c", *TINY, "--wandb-project-name", "a/b"],
        "either")

    # --- rapl_a2c's modes and flags
    base = ["rapl_a2c", *TINY]
    add("a2c/rapl", base, "ok", check=eval_has("mean_alignment", "demo_score"))
    add("a2c/mode-a2c", [*base, "--mode", "a2c"], "ok", check=exists("runs/*/eval.json"))
    add("a2c/mode-macro", [*base, "--mode", "macro"], "ok", check=exists("runs/*/eval.json"))
    add("a2c/authors", [*base, "--authors"], "ok", check=exists("runs/*/eval.json"))
    add("a2c/budget-decisions", [*base, "--budget-unit", "decisions"], "ok")
    add("a2c/update-forward-rollout", [*base, "--update-forward", "rollout"], "ok")
    add("a2c/rollout-unit-steps", [*base, "--rollout-unit", "steps"], "ok",
        check=exists("runs/*/eval.json"))
    add("a2c/rollout-unit-steps-a2c", [*base, "--mode", "a2c", "--rollout-unit", "steps"], "ok")
    add("a2c/seed-stride-40", [*base, "--seed-stride", "40"], "ok")
    add("a2c/scalars-every-huge", [*base, "--scalars-every", str(10 ** 9)], "ok")
    add("a2c/proposer-bpe", [*base, "--proposer", "bpe"], "ok",
        check=eval_has("mean_alignment"))
    add("a2c/routine-library", [*base, "--routine-library", "lib.json"], "ok", setup=lib)
    add("a2c/record-demo", [*base, "--record-demo", "d.npz", "--demo-episodes", "1"], "ok",
        check=exists("d.npz"))
    add("a2c/record-demo-over-its-demo", [*base, "--demo", "mq.npz", "--record-demo",
                                          "mq.npz"], setup=mq, keep=("mq.npz",),
        check=absent("runs/*"))
    for flags in (["--mode", "a2c", "--demo", "mq.npz"], ["--mode", "a2c", "--proposer", "bpe"],
                  ["--mode", "a2c", "--routine-library", "lib.json"],
                  ["--mode", "a2c", "--num-routines", "5"], ["--mode", "a2c", "--prim-coef", "2"],
                  ["--mode", "macro", "--prim-coef", "2"], ["--mode", "a2c", "--authors"],
                  ["--mode", "bogus"], ["--routine-library", "lib.json", "--proposer", "bpe"],
                  ["--routine-library", "lib.json", "--alpha", "3"],
                  ["--num-envs", "0"], ["--num-envs", "2000"],
                  ["--num-envs", str(10 ** 7)], ["--num-steps", "0"],
                  ["--num-steps", str(10 ** 11)], ["--torch-threads", "100000"],
                  ["--torch-threads", "1000"],
                  ["--learning-rate", "nan"], ["--learning-rate", "-1"], ["--gamma", "1.5"],
                  ["--gamma", "nan"], ["--total-timesteps", "0"], ["--eval-episodes", "-1"],
                  ["--eval-episodes", str(10 ** 6)],
                  ["--demo-episodes", "0", "--record-demo", "x.npz"],
                  ["--max-routine-length", "0"], ["--max-routine-length", "1"],
                  ["--min-routine-length", "10", "--max-routine-length", "2"],
                  ["--alpha", "-1"], ["--length-weight", "nan"], ["--ent-coef", "inf"],
                  ["--rmsprop-eps", "0"],
                  ["--demo", "nope.npz"], ["--demo", "garbage.npz"], ["--demo", "lib.json"],
                  ["--demo", "breakout.npz"], ["--routine-library", "garbage.json"],
                  ["--routine-library", "breakout-lib.json"], ["--routine-library", "no.json"],
                  ["--env-id", "NoSuch-v0"], ["--env-id", "Pendulum-v1"],
                  ["--budget-unit", "bogus"], ["--checkpoint-every", "-1"],
                  ["--scalars-every", "0"], ["--log-every", "0"],
                  ["--run-dir", ""], ["--run-dir", "f.txt"], ["--record-demo", "out.txt"],
                  ["--record-demo", ""], ["--record-demo", "d/"],
                  ["--seed-stride", "0"], ["--seed-stride", "2"],
                  ["--seed-stride", str(10 ** 30)], ["--seed", str(2 ** 70)],
                  ["--rollout-unit", "bogus"],
                  ["--rollout-unit", "steps", "--num-steps", str(10 ** 7)],
                  ["--extra-evals", "bogus"],
                  ["--no-such-flag"], ["--reward-scale", "nan"], ["--reward-scale", "inf"]):
        add(f"a2c/{' '.join(flags)[:60]}", [*base, *flags],
            setup=chain(mq, lib, copy("garbage.npz", "garbage.json", "breakout.npz",
                                      "breakout-lib.json"), write("f.txt", "x")),
            keep=("mq.npz", "f.txt"), check=absent("runs/*", "x.npz", "out.txt", "d"))
    for flags in (["--num-routines", "0"], ["--num-routines", str(10 ** 9)],
                  ["--reward-scale", "0"], ["--reward-scale", "-1"], ["--seed", "-1"],
                  ["--env-id", "CartPole-v1"], ["--cuda"], ["--extra-evals", "train"]):
        add(f"a2c/{' '.join(flags)[:60]}", [*base, *flags], "either")

    # --- rapl_ppo's modes and flags
    base = ["rapl_ppo", *TINY]
    add("ppo/rapl", base, "ok", check=eval_has("mean_alignment"))
    add("ppo/mode-ppo", [*base, "--mode", "ppo"], "ok", check=exists("runs/*/eval.json"))
    add("ppo/mode-macro", [*base, "--mode", "macro"], "ok", check=exists("runs/*/eval.json"))
    add("ppo/proposer-bpe", [*base, "--proposer", "bpe"], "ok")
    add("ppo/seed-stride-40", [*base, "--seed-stride", "40"], "ok")
    add("ppo/target-kl", [*base, "--target-kl", "0.01"], "ok")
    for flags in (["--mode", "ppo", "--demo", "mq.npz"], ["--mode", "ppo", "--proposer", "bpe"],
                  ["--mode", "ppo", "--routine-library", "lib.json"],
                  ["--mode", "ppo", "--prim-coef", "2"], ["--mode", "ppo", "--prim-epochs", "2"],
                  ["--mode", "a2c"], ["--num-minibatches", str(10 ** 9)],
                  ["--clip-coef", "-1"],
                  ["--target-kl", "-1"], ["--gae-lambda", "2"],
                  ["--num-envs", str(10 ** 7)], ["--num-steps", str(10 ** 11)],
                  ["--torch-threads", "100000"], ["--scalars-every", "0"],
                  ["--seed-stride", "2"], ["--rollout-unit", "steps"],
                  ["--learning-rate", "-1"], ["--gamma", "2"], ["--demo", "garbage.npz"],
                  ["--record-demo", "x.txt"]):
        add(f"ppo/{' '.join(flags)[:60]}", [*base, *flags],
            setup=chain(mq, lib, copy("garbage.npz")), check=absent("runs/*", "x.txt"))

    # --- the other scripts' new flags
    for script in ("option_critic", "compile_a2c", "rapl_sqil", "gail", "bc"):
        words = [script, "--env-id", "MiniQbert-v0", "--total-timesteps", "500"]
        add(f"{script}/scalars-every-0", [*words, "--scalars-every", "0"],
            check=absent("runs/*"))
        add(f"{script}/torch-threads-100000", [*words, "--torch-threads", "100000"],
            check=absent("runs/*"))
    add("rapl_sqil/proposer-bpe-k0", ["rapl_sqil", "--env-id", "MiniQbert-v0",
                                      "--num-routines", "0", "--proposer", "bpe"])

    # --- divergence (case 6) and bounds (case 5)
    for script in ("rapl_a2c", "rapl_ppo"):
        for flag in ("--reward-scale", "--learning-rate"):
            add(f"case6/{script} {flag} 1e30", [script, *TINY, flag, "1e30"], rc=(3,),
                check=absent("runs/*/eval.json"))
    add("case5/resume-checkpoint-with-1e7-envs", ["rapl_a2c", "--resume", "huge-envs.pt"],
        setup=copy("huge-envs.pt"), timeout=60)

    # --- BPE (case 4)
    add("bpe/mine", ["rg", "mine", "mq.npz", "--proposer", "bpe", "--out", "b.json"], "ok",
        setup=mq, check=exists("b.json"))
    add("bpe/mine-repetitive", ["rg", "mine", "rep.npz", "--proposer", "bpe", "--out",
                                "b.json"], "ok", setup=copy("rep.npz"), timeout=60,
        check=smaller_than("b.json", 1_000_000))
    add("case4/rapl_a2c-repetitive-bpe", ["rapl_a2c", *TINY, "--demo", "rep.npz", "--proposer",
                                          "bpe"], "ok", setup=copy("rep.npz"), timeout=150,
        check=both(smaller_than("runs/*/routines.json", 2_000_000),
                   eval_has("mean_alignment", "demo_score")))
    for flags in (["--proposer", "BPE"], ["--proposer", "bpe", "-k", "0"],
                  ["--proposer", "bpe", "--max-routine-length", "1"],
                  ["--proposer", "bpe", "--alpha", "-1"], ["--proposer", ""],
                  ["--proposer", "bpe", "--out", "b.txt"]):
        add(f"bpe/mine {' '.join(flags)}", ["rg", "mine", "mq.npz", *flags], setup=mq,
            check=absent("b.txt"))
    add("bpe/empty-demo", ["rg", "mine", "empty.npz", "--proposer", "bpe"],
        setup=write("empty.npz", ""))

    # --- --capture-video (cases 1, 2)
    add("case1/compile_a2c-capture-video", ["compile_a2c", *TINY, "--capture-video",
                                            "--compile-iterations", "50"], "ok", timeout=200,
        check=both(exists("runs/*/eval.json"), exists("runs/*/videos/*.gif")))
    add("video/rapl_a2c", ["rapl_a2c", *TINY, "--capture-video"], "ok",
        check=both(exists("runs/*/eval.json"), exists("runs/*/videos/*.gif")))
    add("video/rapl_ppo", ["rapl_ppo", *TINY, "--capture-video"], "ok",
        check=both(exists("runs/*/eval.json"), exists("runs/*/videos/*.gif")))
    add("video/a2c-mode", ["rapl_a2c", *TINY, "--mode", "a2c", "--capture-video"], "ok",
        check=exists("runs/*/videos/*.gif"))
    add("video/option_critic", ["option_critic", "--env-id", "MiniQbert-v0",
                                "--total-timesteps", "500", "--capture-video"], "either")

    def films_kept(cwd: Path, proc: subprocess.CompletedProcess) -> str | None:
        before = json.loads((cwd / "films.json").read_text())
        for rel, digest in before.items():
            path = cwd / rel
            if not path.exists():
                return f"{rel} lost"
            if hashlib.sha256(path.read_bytes()).hexdigest() != digest:
                return f"{rel} overwritten"
        return None

    def film_index(cwd: Path) -> None:
        # The training films are in ./videos/RUN/ (CleanRL's place); the evaluation's, in the
        # run folder, are made again with its eval.json by the resumed run's evaluation.
        copy("run-video", "videos")(cwd)
        films = {str(p.relative_to(cwd)): hashlib.sha256(p.read_bytes()).hexdigest()
                 for p in (cwd / "videos").rglob("*.gif")}
        assert films, "the filmed run has no training films"
        (cwd / "films.json").write_text(json.dumps(films))

    add("case2/resume-capture-video", ["rapl_a2c", "--resume", "run-video",
                                       "--total-timesteps", "800"], "ok", setup=film_index,
        check=films_kept)

    # --- compiled cores
    for value, expect in (("0", "ok"), ("ALL", "ok"),
                          ("sequitur", "ok"), ("bogus", "error"), ("sequitur,foo", "error"),
                          (" ,", "either")):
        add(f"native/{value!r}-mine", ["rg", "mine", "mq.npz"], expect, setup=mq,
            env={"ROUTINE_GYM_NATIVE": value})
    add("native/0-rapl_a2c-minatar", ["rapl_a2c", *TINY, "--env-id", "MinAtar/Breakout-v1"],
        "ok", env={"ROUTINE_GYM_NATIVE": "0"}, check=exists("runs/*/eval.json"))
    add("native/bogus-rapl_a2c", ["rapl_a2c", *TINY], env={"ROUTINE_GYM_NATIVE": "bogus"},
        check=absent("runs/*"))
    add("native/bogus-compile_a2c", ["compile_a2c", *TINY],
        env={"ROUTINE_GYM_NATIVE": "bogus"}, check=absent("runs/*"))
    add("native/report", ["py", "-m", "routine_gym._native"], "ok")
    add("native/bogus-report", ["py", "-m", "routine_gym._native"], "either",
        env={"ROUTINE_GYM_NATIVE": "bogus"})

    # --- resume (cases 9, 11)
    run_a2c = copy("run-a2c")
    add("resume/more-steps", ["rapl_a2c", "--resume", "run-a2c", "--total-timesteps", "800"],
        "ok", setup=run_a2c, check=eval_has("mean_alignment", "demo_score", folder="run-a2c"))
    add("resume/checkpoint-file", ["rapl_a2c", "--resume", "run-a2c/checkpoint.pt",
                                   "--total-timesteps", "800"], "ok", setup=run_a2c)
    add("resume/ppo-more-steps", ["rapl_ppo", "--resume", "run-ppo", "--total-timesteps",
                                  "800"], "ok", setup=copy("run-ppo"),
        check=eval_has("mean_alignment", folder="run-ppo"))
    add("case9/resume-twice-at-once", ["rapl_a2c", "--resume", "run-a2c", "--total-timesteps",
                                       "3000"], setup=run_a2c, twice=True, timeout=240)
    add("resume/locked-by-a-holder", ["rapl_a2c", "--resume", "run-a2c"], setup=run_a2c,
        check=absent("x"), timeout=60)  # the holder is started in run_case (see LOCK_HOLDER)
    for name, words, setup in (
            ("missing", ["--resume", "nope"], None),
            ("empty-folder", ["--resume", "empty"], mkdir("empty")),
            ("garbage-checkpoint", ["--resume", "g.pt"], write("g.pt", "garbage")),
            ("truncated-checkpoint", ["--resume", "truncated.pt"], copy("truncated.pt")),
            ("json-file", ["--resume", "lib.json"], lib),
            ("empty-string", ["--resume", ""], None),
            ("minari", ["--resume", "minari:rg/mq-v0"], None),
            ("other-env", ["--resume", "run-a2c", "--env-id", "MinAtar/Breakout-v1"], run_a2c),
            ("other-num-envs", ["--resume", "run-a2c", "--num-envs", "4"], run_a2c),
            ("other-mode", ["--resume", "run-a2c", "--mode", "a2c"], run_a2c),
            ("threads-100000", ["--resume", "run-a2c", "--torch-threads", "100000"], run_a2c),
            ("ppo-checkpoint", ["--resume", "run-ppo"], copy("run-ppo")),
            ("corrupt-in-folder", ["--resume", "run-a2c"],
             chain(run_a2c, lambda cwd: (cwd / "run-a2c/checkpoint.pt").write_bytes(b"x")))):
        add(f"resume/{name}", ["rapl_a2c", *words], setup=setup, timeout=90)
    add("resume/ppo-given-a2c-checkpoint", ["rapl_ppo", "--resume", "run-a2c"], setup=run_a2c)
    add("resume/finished-same-budget", ["rapl_a2c", "--resume", "run-a2c"], "either",
        setup=run_a2c)

    # --- case 13 and the new user
    add("case13/gitignore", ["py", "-c", (
        f"import sys; t = open({str(REPO / '.gitignore')!r}).read().split();"
        "sys.exit(0 if 'sweeps/' in t and 'wandb/' in t else 'sweeps/ or wandb/ missing')")],
        "ok")
    add("case13/cpu-torch", ["py", "-c", (
        "import sys, torch; sys.exit(0 if torch.version.cuda is None else "
        "'torch ' + torch.__version__ + ' is a CUDA build')")], "ok")
    add("case13/sweep-script-python", ["py", "-c", (
        f"import sys; t = open({str(REPO / 'bench/sweep_cpu.sh')!r}).read();"
        "sys.exit('PYTHON=python default' if 'PYTHON:-python}' in t or "
        "'PYTHON=${PYTHON:-python}' in t else 0)")], "ok")

    # --- experiments: tune at smoke-fair, report --out, bad sweep flags
    add("experiment/tune-smoke-fair", ["rg", "experiment", "run", "tune", "--budget",
                                       "smoke-fair", "--out", "sw"],
        "ok", timeout=400, check=exists("sw/runs/*"))
    add("experiment/tune-smoke", ["rg", "experiment", "run", "tune", "--budget", "smoke",
                                  "--out", "sw"], "either", timeout=60)
    add("experiment/report-out", ["rg", "experiment", "report", "sweep", "--out", "rep"], "ok",
        setup=copy("sweep"), timeout=200, check=exists("rep/report.md"))
    add("experiment/report-default", ["rg", "experiment", "report", "sweep"], "ok",
        setup=copy("sweep"), timeout=200, check=exists("sweep/report/report.md"))
    for name, words, setup in (
            ("report-out-a-file", ["--out", "f.txt"], write("f.txt", "x")),
            ("report-out-empty", ["--out", ""], None),
            ("report-out-s3", ["--out", "s3:b/r"], None),
            ("report-out-under-a-file", ["--out", "f.txt/rep"], write("f.txt", "x"))):
        add(f"experiment/{name}", ["rg", "experiment", "report", "sweep", *words],
            setup=chain(copy("sweep"), setup or (lambda cwd: None)), keep=("f.txt",)
            if setup else (), timeout=120)
    add("experiment/report-missing", ["rg", "experiment", "report", "nope"])
    add("experiment/report-empty-folder", ["rg", "experiment", "report", "e"], "either",
        setup=mkdir("e"))
    add("experiment/report-beside-missing", ["rg", "experiment", "report", "sweep", "--beside",
                                             "nope"], setup=copy("sweep"))
    for flags in (["--budget", "bogus"], ["--jobs", "0"], ["--jobs", str(10 ** 6)],
                  ["--cpus-per-run", "0"], ["--envs", "Nope-v0"], ["--backend", "bogus"],
                  ["--seeds", "-1"], ["--out", ""]):
        add(f"experiment/run {' '.join(flags)}", ["rg", "experiment", "run", "rl", "--budget",
                                                  "smoke", "--out", "sw", *flags],
            check=absent("sw/runs/*"))
    add("experiment/run-unknown", ["rg", "experiment", "run", "nope", "--budget", "smoke",
                                   "--out", "sw"], check=absent("sw"))
    return c


# -- running and classifying --------------------------------------------------------------------

SHARED: Shared  # set in main
_WARNING = re.compile(r"^\S+:\d+: \w*Warning: ")
LOCK_HOLDER = (
    "import sys, time\n"
    "from routine_gym.plumbing.folder_lock import folder_lock\n"
    "with folder_lock(sys.argv[1], what='run', named='--resume ' + sys.argv[1]):\n"
    "    print('held', flush=True)\n"
    "    time.sleep(120)\n")


def _snapshot(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def _digest(path: Path) -> str | None:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None


def error_lines(stderr: str) -> list[str]:
    """The non-empty lines of stderr, less Python's warnings (`FILE:LINE: UserWarning: ...` and
    the source line under it: a run may warn, e.g. of fewer routines than asked, before it
    stops) and argparse's usage block before its `error:` line (the CLI's parser prints
    `usage: ...` above a malformed flag's one-line error, as every argparse program does)."""
    lines, skip = [], False
    for line in stderr.splitlines():
        if skip and line.startswith(" "):  # the source line Python prints under a warning
            continue
        skip = bool(_WARNING.match(line))
        if line.strip() and not skip:
            lines.append(line)
    if lines and lines[0].startswith("usage: ") and ": error: " in lines[-1]:
        lines = lines[-1:]
    return lines


def classify(case: Case, proc: subprocess.CompletedProcess | None, cwd: Path,
             outside: Path, before: set[str], kept: dict[str, str | None]) -> tuple[str, str]:
    """(verdict, reason) of one finished command."""
    if proc is None:
        return "WRONG", "hang: past its timeout"
    stderr = proc.stderr
    if "Traceback (most recent call last)" in stderr:
        return "TRACEBACK", stderr.strip().splitlines()[-1][:200]
    # What must not be written, whatever the exit code.
    odd = [p for p in cwd.rglob("*") if re.search(r"(^|/)(minari|s3):", p.name)]
    odd += [p for p in SHARED.minari.rglob("*") if ":" in p.name]
    if odd:
        return "WRONG", f"wrote {odd[0].name!r}"
    stray = sorted(set(p.name for p in outside.iterdir()) - {"w"})
    if stray:
        return "WRONG", f"wrote outside its folder: {stray}"
    for rel, digest in kept.items():
        if _digest(cwd / rel) != digest:
            return "WRONG", f"{rel} changed or lost"
    lines = error_lines(stderr)
    if case.expect in ("error", "either") and proc.returncode in case.rc:
        if len(lines) != 1:
            return "WRONG", f"rc {proc.returncode} with {len(lines)} lines on stderr"
        after = _snapshot(cwd)
        new_runs = [p for p in after - before if p.startswith("runs/") and p.count("/") == 1]
        # Refused (2): no run folder may be left. Diverged (3): its folder keeps the logs up to
        # the step it stopped at, as docs/errors.md says.
        if new_runs and proc.returncode == 2:
            return "WRONG", f"refused but left {new_runs[0]}"
        if case.check and case.expect == "error":
            why = case.check(cwd, proc)
            if why:
                return "WRONG", why
        return "GOOD", lines[0][:160]
    if proc.returncode == 0:
        if case.expect == "error":
            return "WRONG", "rc 0 where it should fail"
        if case.check and case.expect == "ok":
            why = case.check(cwd, proc)
            if why:
                return "WRONG", why
        return "GOOD", "rc 0"
    tail = lines[-1][:160] if lines else ""
    return "WRONG", f"rc {proc.returncode} (expected {case.expect}): {tail}"


def run_case(case: Case, scratch: Path) -> Outcome:
    outside = scratch / re.sub(r"[^A-Za-z0-9_.=-]+", "_", case.name)[:80]
    outside.mkdir(parents=True)
    cwd = outside / "w"
    cwd.mkdir()
    if case.setup:
        case.setup(cwd)
    before = _snapshot(cwd)
    kept = {rel: _digest(cwd / rel) for rel in case.keep}
    start = time.monotonic()
    argv = SHARED.argv(case.words)
    env = SHARED.env(cwd, case.env)
    holder = None
    if case.name == "resume/locked-by-a-holder":
        holder = subprocess.Popen([str(SHARED.bin / "python"), "-c", LOCK_HOLDER, "run-a2c"],
                                  cwd=cwd, env=env, stdout=subprocess.PIPE, text=True)
        holder.stdout.readline()  # held
    try:
        if case.twice:
            procs = [subprocess.Popen(argv, cwd=cwd, env=env, stdout=subprocess.PIPE,
                                      stderr=subprocess.PIPE, text=True,
                                      stdin=subprocess.DEVNULL) for _ in range(2)]
            results = []
            for p in procs:
                out, err = p.communicate(timeout=case.timeout)
                results.append(subprocess.CompletedProcess(argv, p.returncode, out, err))
            codes = sorted(r.returncode for r in results)
            refused = [r for r in results if r.returncode != 0]
            seconds = time.monotonic() - start
            if any("Traceback" in r.stderr for r in results):
                return Outcome(case.name, "TRACEBACK", "a traceback", None, seconds,
                               "".join(r.stderr for r in results)[-1500:])
            if codes == [0, 2] and len(refused[0].stderr.strip().splitlines()) == 1:
                return Outcome(case.name, "GOOD", refused[0].stderr.strip()[:160], 0, seconds,
                               "")
            return Outcome(case.name, "WRONG", f"exit codes {codes} (one must refuse)", None,
                           seconds, "".join(r.stderr for r in results)[-1500:])
        try:
            proc = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True,
                                  timeout=case.timeout, stdin=subprocess.DEVNULL)
        except subprocess.TimeoutExpired:
            proc = None
    finally:
        if holder:
            holder.kill()
            holder.wait()
    verdict, reason = classify(case, proc, cwd, outside, before, kept)
    return Outcome(case.name, verdict, reason, proc.returncode if proc else None,
                   time.monotonic() - start, proc.stderr[-1500:] if proc else "")


def main() -> int:
    global SHARED
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-k", default=None, help="only the cases whose name holds this")
    parser.add_argument("-j", "--jobs", type=int, default=3, help="cases at a time (3)")
    parser.add_argument("-v", "--verbose", action="store_true", help="a line for every case")
    parser.add_argument("--venv", default=str(REPO / ".venv"), help="the venv to run (.venv)")
    parser.add_argument("--repo", default=None,
                        help="the checkout whose algos/ to run, with --venv its venv (this one)")
    parser.add_argument("--json", default=None, help="write every outcome here")
    parser.add_argument("--keep", action="store_true", help="keep the scratch folder")
    args = parser.parse_args()
    global ALGOS
    if args.repo:  # main's scripts beside main's venv: the counts before a fix
        ALGOS = Path(args.repo).resolve() / "algos"
    scratch = Path(tempfile.mkdtemp(prefix="probe46-"))
    (scratch / "shared").mkdir()
    SHARED = Shared(scratch / "shared", Path(args.venv) / "bin")
    todo = [case for case in cases() if not args.k or args.k in case.name]
    names = [case.name for case in todo]
    assert len(names) == len(set(names)), "case names must be unique"
    start = time.monotonic()
    print(f"probe: {len(todo)} cases; set-up in {scratch}", flush=True)
    SHARED.make()
    print(f"probe: set-up took {time.monotonic() - start:.0f} s", flush=True)
    outcomes: list[Outcome] = []
    with ThreadPoolExecutor(args.jobs) as pool:
        for outcome in pool.map(lambda case: run_case(case, scratch / "cases"), todo):
            outcomes.append(outcome)
            if args.verbose or outcome.verdict != "GOOD":
                print(f"{outcome.verdict:9} {outcome.name}: {outcome.reason} "
                      f"({outcome.seconds:.0f} s)", flush=True)
    counts = {v: sum(o.verdict == v for o in outcomes) for v in ("GOOD", "TRACEBACK", "WRONG")}
    print(f"probe: {len(outcomes)} cases in {time.monotonic() - start:.0f} s: "
          f"{counts['GOOD']} good, {counts['TRACEBACK']} traceback, {counts['WRONG']} wrong")
    if args.json:
        Path(args.json).write_text(json.dumps([o.__dict__ for o in outcomes], indent=1))
    if not args.keep:
        shutil.rmtree(scratch, ignore_errors=True)
    return 0 if counts["TRACEBACK"] == counts["WRONG"] == 0 else 1


if __name__ == "__main__":
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from common import children_die_with_me  # no orphan commands after a SIGTERM

    children_die_with_me()
    sys.exit(main())
