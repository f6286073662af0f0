"""The flags memory or threads follow from have upper bounds, checked before any work, and the
storage a script sizes from them is checked against the memory available where it is allocated
(issue 46: `--torch-threads 100000` segfaulted, `--num-envs 10^7` hung at 2 GB, also from a
checkpoint, `--num-steps 10^11` died of a MemoryError traceback). Every numeric flag's bound or
why it needs none: tests/test_args_domains.py."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from one_line import assert_one_line_error
from script_loader import ALGOS, load_script

from routine_gym.plumbing import memory
from routine_gym.plumbing.arguments import MAX_TORCH_THREADS
from routine_gym.plumbing.errors import UsageError

BIN = Path(sys.executable).parent


def user(script: str, *words: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(cwd), "LANG": "C.UTF-8"}
    return subprocess.run([str(BIN / "python"), str(ALGOS / f"{script}.py"), *words], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=120,
                          stdin=subprocess.DEVNULL)


@pytest.mark.parametrize(("words", "names"), [
    (("--torch-threads", "100000"),
     ("--torch-threads needs to be ≤", "actual value: 100000", "CPUs this process may use")),
    (("--torch-threads", str(MAX_TORCH_THREADS + 1)), ("--torch-threads needs to be ≤",)),
    (("--num-envs", "10000000"), ("--num-envs needs to be ≤ 1,024, actual value: 10000000",)),
    (("--num-steps", str(10**11), "--total-timesteps", str(10**12)),
     ("--num-steps needs to be ≤ 1,048,576, actual value: 100000000000",)),
    (("--eval-episodes", str(10**9)), ("--eval-episodes needs to be ≤ 10,000",)),
])
def test_a_flag_past_its_upper_bound_is_refused_in_one_line(words, names, tmp_path):
    proc = user("rapl_a2c", "--env-id", "MiniQbert-v0", "--run-dir", "runs", *words,
                cwd=tmp_path)
    assert_one_line_error(proc, *names, prefix="rapl_a2c.py: error: ")
    assert not (tmp_path / "runs").exists()  # refused before a run folder was made


def test_check_memory_refuses_more_than_is_available(monkeypatch):
    monkeypatch.setattr(memory, "available_memory", lambda: 2_000_000_000)
    memory.check_memory(2_000_000_000, "x")  # exactly what is there: fine
    with pytest.raises(UsageError, match=r"^the storage needs 2\.5 GB, more than the 2 GB of "
                                         r"memory available$"):
        memory.check_memory(2_500_000_000, "the storage")
    monkeypatch.setattr(memory, "available_memory", lambda: None)
    memory.check_memory(10**18, "x")  # unknown: not refused


def test_the_available_memory_is_read_from_the_system():
    available = memory.available_memory()
    assert available is None or 0 < available < 2**60


#: A tiny run of each script whose storage is checked, and the words of its refusal.
STORAGE = {
    "rapl_a2c": ({"mode": "a2c", "total_timesteps": 64}, "the rollout storage (--num-steps 5 × "
                                                         "--num-envs 16"),
    "rapl_ppo": ({"mode": "ppo", "total_timesteps": 512}, "the rollout storage (--num-steps"),
    "option_critic": ({"total_timesteps": 64}, "the rollout storage (--num-steps 5"),
    "gail": ({"total_timesteps": 64, "num_envs": 2, "num_steps": 16, "num_minibatches": 2,
              "disc_minibatches": 2}, "the rollout storage (--num-steps 16 × --num-envs 2"),
    "rapl_sqil": ({"total_timesteps": 64}, "the replay memory (--buffer-size 100,000"),
    "bc": ({"gradient_steps": 5}, "a batch (--batch-size 64"),
    "compile_a2c": ({"total_timesteps": 64, "compile_iterations": 2, "compile_option_steps": 2},
                    "the rollout storage (--num-steps 5 × --num-envs 16"),
}


def test_every_script_checks_its_storage():
    assert set(STORAGE) == {path.stem for path in ALGOS.glob("*.py")}


@pytest.mark.parametrize("script", sorted(STORAGE))
def test_storage_that_cannot_fit_is_refused_before_training(script, tmp_path, monkeypatch):
    monkeypatch.setattr(memory, "available_memory", lambda: 1_000)
    module = load_script(script, f"bounds_{script}")
    setting, words = STORAGE[script]
    args = module.Args(env_id="MiniQbert-v0", run_dir=str(tmp_path), eval_episodes=0,
                       torch_threads=1, **setting)
    with pytest.raises(UsageError, match="more than the 1 KB of memory available") as refused:
        module.main(args)
    assert words in str(refused.value)
