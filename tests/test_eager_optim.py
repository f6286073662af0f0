"""`routine_gym.plumbing.eager_optim`: RMSprop and Adam step without importing TorchDynamo, and
their numbers are torch's own bit for bit. Each side runs in a fresh interpreter, since the
import (or its absence) is per process."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from script_loader import ALGOS

from routine_gym.plumbing.eager_optim import SWITCH

#: Five seeded updates of each optimizer the scripts use, a state_dict round trip into a new
#: optimizer and three updates more; prints every parameter and whether torch._dynamo was
#: imported.
STEPS = """
import json, sys, torch
from routine_gym.plumbing.eager_optim import eager_optimizers
changed = eager_optimizers()
out = {"changed": changed}
for name, make in (("rmsprop", lambda p: torch.optim.RMSprop(p, lr=7e-4, alpha=0.99, eps=1e-5)),
                   ("adam", lambda p: torch.optim.Adam(p, lr=5e-4, eps=1e-5)),
                   ("adam-fused", lambda p: torch.optim.Adam(p, lr=5e-4, fused=True))):
    torch.manual_seed(0)
    model = torch.nn.Sequential(torch.nn.Linear(4, 8), torch.nn.Tanh(), torch.nn.Linear(8, 3))
    opt = make(model.parameters())
    for i in range(8):
        if i == 5:  # as a resumed run: a new optimizer from the saved state
            state = opt.state_dict()
            opt = make(model.parameters())
            opt.load_state_dict(state)
        loss = model(torch.randn(6, 4)).pow(2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    out[name] = [p.detach().flatten().tolist() for p in model.parameters()]
out["dynamo"] = "torch._dynamo" in sys.modules
print(json.dumps(out))
"""


def _python(code_or_words: list[str], switch: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, SWITCH: switch}
    return subprocess.run([sys.executable, *code_or_words], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


def test_the_eager_step_is_torchs_update_without_the_dynamo_import(tmp_path):
    eager, torchs = (json.loads(_python(["-c", STEPS], s, tmp_path).stdout) for s in ("1", "0"))
    assert eager["changed"] == ["Optimizer.add_param_group", "Optimizer.zero_grad",
                                "Optimizer.state_dict", "Optimizer.load_state_dict",
                                "RMSprop.step", "Adam.step"]
    assert torchs["changed"] == []
    assert eager["dynamo"] is False and torchs["dynamo"] is True
    for name in ("rmsprop", "adam", "adam-fused"):
        assert eager[name] == torchs[name], name  # exactly equal floats


def _losses(run_dir: Path) -> dict[str, list[float]]:
    """Every `losses/` scalar of the run, step by step."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    (folder,) = [p for p in run_dir.iterdir() if p.is_dir()]
    ea = EventAccumulator(str(folder))
    ea.Reload()
    return {tag: [e.value for e in ea.Scalars(tag)] for tag in ea.Tags()["scalars"]
            if tag.startswith("losses/")}


#: Runs a script as `python SCRIPT ARGS` does, then says on stderr whether torch._dynamo was
#: imported in its process.
AS_SCRIPT = ("import runpy, sys\nscript = sys.argv[1]\nsys.argv = sys.argv[1:]\ntry:\n"
             "    runpy.run_path(script, run_name='__main__')\nfinally:\n"
             "    print('dynamo imported:', 'torch._dynamo' in sys.modules, file=sys.stderr)")


def test_a_seeded_script_run_is_the_same_either_way(tmp_path):
    evals, losses = {}, {}
    for switch in ("1", "0"):
        run_dir = tmp_path / f"run{switch}"
        proc = _python(["-c", AS_SCRIPT, str(ALGOS / "rapl_a2c.py"), "--mode", "rapl", "--env-id",
                        "MinAtar/Breakout-v1", "--total-timesteps", "1500", "--num-envs", "4",
                        "--eval-episodes", "3", "--seed", "3", "--run-dir", str(run_dir),
                        "--torch-threads", "1", "--scalars-every", "1"], switch, tmp_path)
        assert proc.returncode == 0, proc.stderr[-2000:]
        # the script's run_script turns it on; the switch turns it off
        assert f"dynamo imported: {switch == '0'}" in proc.stderr
        (path,) = run_dir.glob("*/eval.json")
        evals[switch] = json.loads(path.read_text())
        losses[switch] = _losses(run_dir)
    assert evals["1"]["returns"] == evals["0"]["returns"]
    # every update's losses, the weights' history: equal to the last bit
    assert len(losses["1"]["losses/value_loss"]) >= 5
    assert losses["1"] == losses["0"]


def test_it_stands_aside_when_dynamo_is_loaded_or_switched_off(tmp_path):
    code = ("import sys, torch, torch._dynamo\n"
            "from routine_gym.plumbing.eager_optim import eager_optimizers\n"
            "print(eager_optimizers())")
    assert _python(["-c", code], "1", tmp_path).stdout.strip() == "[]"
    code = ("from routine_gym.plumbing.eager_optim import eager_optimizers\n"
            "print(eager_optimizers())")
    assert _python(["-c", code], "0", tmp_path).stdout.strip() == "[]"
