"""Benchmark: wall time of CompILE's fit (`algos/compile_a2c.py`'s phase 1) on each shipped MinAtar
demo, against the same fit with the recognition GRU as the torch loop and as the `GRUCell` loop it
was before.

The acceptance: CompILE's fit on each shipped MinAtar demo (`demos/MinAtar-*-v1.npz`) within
60 s of wall time on 2 cores, with the script's defaults.

For each game (`--envs`, default the five MinAtar games) this file runs itself as a worker in a
subprocess (nothing, threads or caches, is shared between measurements) and times
`learn_options` of `compile_a2c.py` (the script imported as a module; its `Args` defaults, so
the benchmark stays in step with the script): the demo's states in the agent's view
(`agent_view_states`, replayed from the demo's seeds), `train_compile` (the ELBO's Adam steps),
`segment` (the hard segmentation of the whole demo), `fit_options` (the decoder and termination
head), and the whole call, which is what a run waits for before its controller starts (`total
s`; the verdict is on it). The worker sets what `start_run` sets before it (the seeds,
distribution argument checks off, `torch.set_num_threads` when `--torch-threads` > 0: the
script's default 0 is torch's own thread count) and builds the observation space, action count
and action meanings as `main` does (one env made with `make_env`); env creation and loading the
demo are outside the timing. `CPU s` is the worker's process CPU time (all its threads) over the
same call, which a shared machine disturbs less than wall time.

Two peers, measured in the same run right after each game (`--no-torch-loop`, `--no-peer` leave
them out):

- the torch loop (`--torch-loop`, kind ``torch-loop``): the same fit with
  `ROUTINE_GYM_COMPILE_GRU=torch`, so `masked_gru` runs its loops in torch operations, as every
  fit did before the compiled loops (`routine_gym/_masked_gru.cpp`);
- the GRUCell loop (`--peer`, kind ``peer``): the recognition GRU as routine-gym had it before
  `routine_gym/baselines/compile/masked_gru.py` (git HEAD~1 of that change):
  `hidden = self.gru(inputs[:, t], hidden) * mask[:, t, None]` over the window, a
  `torch.nn.GRUCell` called on the GRU's inputs x, once per segment. The worker swaps
  `CompILE._masked_gru` for that loop and `CompILE.recognise` for its current source with the
  one line that projects x to the input gates once per window replaced by `gates = x` (so the
  cell projects x at every step, as before). Should that line ever change, the peer falls back
  to a loop from the input gates (the GRUCell's math written step by step with ordinary autograd
  ops, which leaves out the per-step input projection, so it costs a little less than the old
  code); the report says which peer ran. Before timing, the worker checks on tiny inputs that
  its loop gives `masked_gru`'s outputs and gradients, and that the swapped `recognise` gives
  the current one's boundaries and latents.

`--iterations N` overrides `compile_iterations` for quick tries; the verdict is then not given.

Usage:
    python bench/bench_compile_fit.py
    python bench/bench_compile_fit.py --envs MinAtar/Breakout-v1 --iterations 10 \\
        --out /tmp/cf/compile_fit.md
    python bench/bench_compile_fit.py --no-peer --no-torch-loop --torch-threads 1
    python bench/bench_compile_fit.py --from-json bench/results/compile_fit.json
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import json
import os
import shlex
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from types import ModuleType

from common import base_machine_info, git_head, load_average, memory, tuning_env_vars

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "algos" / "compile_a2c.py"
GAMES = ("MinAtar/Asterix-v1", "MinAtar/Breakout-v1", "MinAtar/Freeway-v1",
         "MinAtar/Seaquest-v1", "MinAtar/SpaceInvaders-v1")
#: The acceptance: the whole fit within this many seconds of wall time.
TARGET_SECONDS = 60.0
#: The `Args` fields of compile_a2c.py that set the fit (reported with the figures).
FIT_SETTINGS = ("seed", "compile_iterations", "compile_batch_size", "compile_window",
                "compile_latents", "compile_segments", "compile_hidden", "compile_prior_rate",
                "compile_learning_rate", "compile_option_steps", "num_options", "torch_threads")
#: The line of `CompILE.recognise` the peer removes (the input gates, once per window).
PROJECTION = "gates = F.linear(x, self.gru.weight_ih, self.gru.bias_ih)"
#: The peers, in the order they run after ours: the report's column name and what they are.
PEERS = {
    "torch-loop": ("torch loop", "the same fit with `ROUTINE_GYM_COMPILE_GRU=torch` (masked_gru's "
                   "loops in torch operations, as the fit ran before the compiled loops)"),
    "peer": ("GRUCell loop", "the same fit with the recognition GRU as the GRUCell loop of "
             "routine-gym before `masked_gru.py`"),
}
#: The functions of the script whose wall time the worker takes, and their report names.
PHASES = {"agent_view_states": "states", "train_compile": "train", "segment": "segment",
          "fit_options": "options"}


@dataclass
class Result:
    """One worker's measurement: one game, ours or the peer."""

    env_id: str
    kind: str  # "ours", or a peer: "torch-loop" or "peer" (PEERS)
    command: str
    load_before: str
    torch_threads: str = ""
    decisions: int = 0
    episodes: int = 0
    states_s: float | None = None
    train_s: float | None = None
    segment_s: float | None = None
    options_s: float | None = None
    total_s: float | None = None
    cpu_s: float | None = None
    final_loss: float | None = None
    codes: list[int] = field(default_factory=list)
    segments: int = 0
    peer_gru: str = ""
    check: str = ""
    gru: str = ""
    returncode: int = 0
    error: str = ""


def load_script() -> ModuleType:
    """`algos/compile_a2c.py` as a module (as `tests/script_loader.py` imports the scripts)."""
    name = "bench_compile_a2c"
    spec = importlib.util.spec_from_file_location(name, SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while the file runs
    spec.loader.exec_module(module)
    return module


def script_settings(iterations: int | None, threads: int) -> tuple[dict, dict]:
    """The fit's settings of this run and the script's defaults."""
    defaults = {k: getattr(load_script().Args(), k) for k in FIT_SETTINGS}
    settings = dict(defaults, torch_threads=threads)
    if iterations is not None:
        settings["compile_iterations"] = iterations
    return settings, defaults


def shipped_demo(env_id: str) -> Path:
    return REPO / "demos" / f"{env_id.replace('/', '-')}.npz"


# ---------------------------------------------------------------------------------------------
# The peer: the recognition GRU as the GRUCell loop (routine-gym before masked_gru.py)
# ---------------------------------------------------------------------------------------------


def grucell_loop(self, inputs, mask):
    """`CompILE._masked_gru` before masked_gru.py, verbatim: GRU over `[B, T, H]` inputs x, its
    state multiplied by `mask[:, t]` after each step."""
    import torch

    hidden = inputs.new_zeros(inputs.shape[0], inputs.shape[2])
    outputs = []
    for t in range(inputs.shape[1]):
        hidden = self.gru(inputs[:, t], hidden) * mask[:, t, None]
        outputs.append(hidden)
    return torch.stack(outputs, dim=1)


def gates_loop(self, gates, mask):
    """The same loop from the input gates `W_ih x + b_ih` (`[B, T, 3H]`): the GRUCell's math step
    by step with ordinary autograd ops (the fallback peer: no per-step input projection)."""
    import torch
    import torch.nn.functional as F

    h = gates.shape[-1] // 3
    hidden = gates.new_zeros(gates.shape[0], h)
    outputs = []
    for t in range(gates.shape[1]):
        gi, gh = gates[:, t], F.linear(hidden, self.gru.weight_hh, self.gru.bias_hh)
        r = torch.sigmoid(gi[:, :h] + gh[:, :h])
        z = torch.sigmoid(gi[:, h:2 * h] + gh[:, h:2 * h])
        n = torch.tanh(gi[:, 2 * h:] + r * gh[:, 2 * h:])
        hidden = ((1 - z) * n + z * hidden) * mask[:, t, None]
        outputs.append(hidden)
    return torch.stack(outputs, dim=1)


def old_recognise():
    """`CompILE.recognise` with the GRU fed x instead of the input gates, or None when its
    source no longer has the projection line once."""
    import __future__

    import inspect
    import textwrap

    from routine_gym.baselines.compile import model as model_module

    source = textwrap.dedent(inspect.getsource(model_module.CompILE.recognise))
    if source.count(PROJECTION) != 1:
        return None
    code = compile(source.replace(PROJECTION, "gates = x"),
                   inspect.getsourcefile(model_module.CompILE), "exec",
                   flags=__future__.annotations.compiler_flag, dont_inherit=True)
    namespace: dict = {}
    exec(code, vars(model_module), namespace)  # noqa: S102  (the module's own source, one line changed)
    return namespace["recognise"]


def check_loop(loop, takes_gates: bool) -> str:
    """The loop against `masked_gru` on a tiny float64 input: outputs and gradients."""
    import torch
    import torch.nn.functional as F

    from routine_gym.baselines.compile.masked_gru import masked_gru

    generator = torch.Generator().manual_seed(0)
    cell = torch.nn.GRUCell(4, 4).double()  # input size = hidden size, as in CompILE
    holder = type("Holder", (), {"gru": cell})()
    x = torch.randn(3, 7, 4, dtype=torch.float64, generator=generator, requires_grad=True)
    mask = torch.rand(3, 7, dtype=torch.float64, generator=generator)
    mask[:, 0], mask[1, 3] = 1.0, 0.0
    weight = torch.randn(3, 7, 4, dtype=torch.float64, generator=generator)
    values = []
    for fused in (True, False):
        x.grad = None
        cell.zero_grad()
        gates = F.linear(x, cell.weight_ih, cell.bias_ih)
        if fused:
            out = masked_gru(gates, mask, cell.weight_hh, cell.bias_hh)
        else:
            out = loop(holder, gates if takes_gates else x, mask)
        (out * weight).sum().backward()
        values.append([out.detach().clone(), x.grad.clone(),
                       *(p.grad.clone() for p in cell.parameters())])
    for fused_value, loop_value in zip(*values, strict=True):
        assert torch.allclose(fused_value, loop_value, rtol=1e-9, atol=1e-11), \
            "the peer's GRU loop differs from masked_gru"
    return "loop = masked_gru (float64 outputs and gradients, 1e-9)"


def check_recognise(recognise, env_id: str, obs_shape, obs_dtype: str, num_actions: int) -> str:
    """The swapped `recognise` against the current one on a tiny model of the env."""
    import torch

    from routine_gym.baselines.compile.model import CompILE, CompILEConfig

    torch.manual_seed(0)
    model = CompILE(CompILEConfig(env_id=env_id, obs_shape=tuple(obs_shape), obs_dtype=obs_dtype,
                                  num_actions=num_actions, num_segments=3, window=6,
                                  hidden_dim=16))
    generator = torch.Generator().manual_seed(1)
    features = torch.randn(2, 6, model.state_in.in_features, generator=generator)
    actions = torch.randint(num_actions, (2, 6), generator=generator)
    outs = []
    for old in (False, True):
        generator.manual_seed(2)
        with torch.no_grad():
            if old:
                saved = CompILE._masked_gru
                CompILE._masked_gru = grucell_loop
                try:
                    outs.append(recognise(model, features, actions, generator=generator))
                finally:
                    CompILE._masked_gru = saved
            else:
                outs.append(model.recognise(features, actions, generator=generator))
    for name in ("boundaries", "latent_logits", "latents"):
        assert torch.allclose(getattr(outs[0], name), getattr(outs[1], name), atol=1e-5), \
            f"the peer's recognise differs from the current one ({name})"
    return "old recognise = current (tiny model, boundaries and latents, 1e-5)"


def use_peer(env_id: str, obs_space, num_actions: int) -> tuple[str, str]:
    """Swap the GRUCell loop in (after the checks); returns what ran and what was checked."""
    from routine_gym.baselines.compile.model import CompILE

    recognise = old_recognise()
    if recognise is None:
        check = check_loop(gates_loop, takes_gates=True)
        CompILE._masked_gru = gates_loop
        return ("fallback: GRUCell math from the input gates, step by step (recognise's "
                "projection line not found)"), check
    check = check_loop(grucell_loop, takes_gates=False)
    check += "; " + check_recognise(recognise, env_id, obs_space.shape, str(obs_space.dtype),
                                    num_actions)
    CompILE._masked_gru = grucell_loop
    CompILE.recognise = recognise
    return "GRUCell loop on x (HEAD~1 of masked_gru.py)", check


# ---------------------------------------------------------------------------------------------
# The worker: one fit, timed
# ---------------------------------------------------------------------------------------------


class _NullWriter:
    def add_scalar(self, *args, **kwargs) -> None:
        pass


def worker(args) -> None:
    """`learn_options` of compile_a2c.py on one game's shipped demo; prints one JSON line."""
    import warnings

    import torch

    import routine_gym
    from routine_gym.plumbing.run import seed_and_tune

    warnings.filterwarnings("ignore", category=DeprecationWarning)
    script = load_script()
    routine_gym.register_envs()
    sargs = script.Args(env_id=args.worker_env, torch_threads=args.torch_threads)
    if args.iterations is not None:
        sargs.compile_iterations = args.iterations
    seed_and_tune(sargs.seed, sargs.torch_threads)  # what start_run sets before the fit
    # What main does before learn_options.
    probe = script.make_env(sargs.env_id, sargs.seed, 0, training=True,
                            env_kwargs=script.train_env_kwargs(sargs))()
    obs_space, num_actions = probe.observation_space, int(probe.action_space.n)
    meanings = getattr(probe.unwrapped, "get_action_meanings", lambda: None)()
    probe.close()
    demo, sargs.demo = script.load_demo(sargs.env_id, sargs.demo, purpose="compile_a2c.py")

    peer_gru, check = "", ""
    if args.worker == "peer":
        peer_gru, check = use_peer(sargs.env_id, obs_space, num_actions)
        print(f"# peer: {peer_gru}; checked: {check}", flush=True)
        gru = "GRUCell loop"
    else:
        from routine_gym.baselines.compile import masked_gru

        probe_tensor = torch.zeros(1)
        gru = (f"compiled loops ({masked_gru._core.simd()})"
               if masked_gru._compiled(*[probe_tensor] * 4) else "torch loop")

    seconds: dict[str, float] = {}

    def timed(name: str, function):
        def wrapper(*a, **k):
            start = time.perf_counter()
            try:
                return function(*a, **k)
            finally:
                seconds[name] = seconds.get(name, 0.0) + time.perf_counter() - start

        return wrapper

    for name in PHASES:
        setattr(script, name, timed(name, getattr(script, name)))
    cpu0, wall0 = time.process_time(), time.perf_counter()
    _, meta = script.learn_options(sargs, demo, obs_space, num_actions, meanings,
                                   torch.device("cpu"), _NullWriter())
    total, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    missing = [name for name in PHASES if name not in seconds]
    if missing:
        raise RuntimeError(f"learn_options no longer calls {', '.join(missing)}")
    steps = script.decision_steps(demo)
    print(json.dumps({
        "torch_threads": torch.get_num_threads(), "decisions": int(len(steps.actions)),
        "episodes": int(demo.num_episodes),
        **{f"{short}_s": seconds[name] for name, short in PHASES.items()},
        "total_s": total, "cpu_s": cpu,
        "final_loss": meta["elbo_log"][-1]["loss"] if meta["elbo_log"] else None,
        "codes": [int(c) for c in meta["codes"]],
        "segments": len(meta["segmentation"]["codes"]), "peer_gru": peer_gru, "check": check,
        "gru": gru,
    }), flush=True)


def run_worker(env_id: str, kind: str, args) -> Result:
    """This file's `--worker` for one game and kind (ours, or a peer of PEERS) in a subprocess;
    reads its JSON line. The torch-loop peer is ours with `ROUTINE_GYM_COMPILE_GRU=torch`; the
    others run without the variable, whatever this process's environment holds."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker",
           "peer" if kind == "peer" else "ours", "--worker-env", env_id, "--torch-threads",
           str(args.torch_threads)]
    if args.iterations is not None:
        cmd += ["--iterations", str(args.iterations)]
    from routine_gym.baselines.compile.masked_gru import GRU_VARIABLE

    env = {k: v for k, v in os.environ.items() if k != GRU_VARIABLE}
    shown = shlex.join(cmd)
    if kind == "torch-loop":
        env[GRU_VARIABLE] = "torch"
        shown = f"{GRU_VARIABLE}=torch {shown}"
    result = Result(env_id, kind, shown, load_average())
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, env=env)
    result.returncode = proc.returncode
    line = next((x for x in reversed(proc.stdout.splitlines()) if x.startswith("{")), None)
    if proc.returncode != 0 or line is None:
        result.error = proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "?"
        return result
    data = json.loads(line)
    threads = data.pop("torch_threads")
    result.torch_threads = f"{threads}" + (" (default)" if args.torch_threads == 0 else "")
    for key, value in data.items():
        setattr(result, key, value)
    return result


# ---------------------------------------------------------------------------------------------
# The report
# ---------------------------------------------------------------------------------------------


def machine_info() -> dict[str, str]:
    import torch

    info = {
        **base_machine_info(),
        "memory": memory(),
        "torch": f"{torch.__version__} (default threads {torch.get_num_threads()}, "
                 f"interop {torch.get_num_interop_threads()})",
        "thread and memory env vars": tuning_env_vars(),
        "compile_a2c.py sha256": hashlib.sha256(SCRIPT.read_bytes()).hexdigest()[:16],
        "git HEAD": git_head(REPO, [str(SCRIPT), "routine_gym/baselines/compile",
                                    "routine_gym/imitation", "routine_gym/networks.py"]),
    }
    return info






def _num(value: float | None, spec: str = ".1f") -> str:
    return "–" if value is None else format(value, spec)


def verdict(ours: Result, settings: dict, defaults: dict) -> str:
    if ours.error or ours.total_s is None:
        return "not measured"
    if settings["compile_iterations"] != defaults["compile_iterations"]:
        return (f"not judged (--iterations {settings['compile_iterations']}, the script's "
                f"default is {defaults['compile_iterations']})")
    return "meets" if ours.total_s <= TARGET_SECONDS else "misses"


def render(results: list[Result], raw: dict) -> str:
    settings, defaults = raw["settings"], raw["defaults"]
    by_game: dict[str, dict[str, Result]] = {}
    for r in results:
        by_game.setdefault(r.env_id, {})[r.kind] = r
    peers_ran = [kind for kind in PEERS if any(r.kind == kind for r in results)]
    changed = [f"{k} {settings[k]} (default {defaults[k]})" for k in settings
               if settings[k] != defaults[k]]
    peer_head = "".join(f" {PEERS[kind][0]} total s | ×ours |" for kind in peers_ran)
    peer_sep = "---|---|" * len(peers_ran)
    grus = sorted({r.gru for r in results if r.kind == "ours" and r.gru})
    lines = [
        "# CompILE's fit on the shipped MinAtar demos (compile_a2c.py's phase 1)",
        "",
        "Produced by `bench/bench_compile_fit.py`; the command, machine and load are below. "
        "Each figure is one run of compile_a2c.py's `learn_options` (imported from the script, "
        "with its `Args` defaults) on the game's shipped demo, in its own process: `states s` "
        "the demo's states in the agent's view (replayed from its seeds), `train s` "
        "`train_compile` (the ELBO), `segment s` `segment`, `options s` `fit_options`, `total "
        "s` the whole call (these and the small rest: picking the codes, describing the "
        "options). `CPU s`: the process's CPU time over the same call (all threads). "
        f"Target: `total s` ≤ {TARGET_SECONDS:g} s per game with the script's defaults."
        + (f" Ours ran the recognition GRU as {', '.join(grus)}." if grus else "")
        + "".join(f" `{PEERS[kind][0]} total s`: {PEERS[kind][1]}, measured right after;"
                  for kind in peers_ran)
        + (" `×ours` = that total / ours." if peers_ran else ""),
        "",
        "Settings: " + ", ".join(f"{k} {v}" for k, v in settings.items())
        + (" (torch's default thread count)" if settings["torch_threads"] == 0 else "") + ".",
    ]
    if changed:
        shortened = settings["compile_iterations"] != defaults["compile_iterations"]
        lines += ["", f"**Not the script's defaults:** {'; '.join(changed)}."
                  + (" The target is not judged on a shortened fit." if shortened else "")]
    lines += [
        "",
        "| game | decisions | episodes | load (1/5/15) before | torch threads | states s "
        "| train s | segment s | options s | total s | CPU s | final −ELBO |"
        f"{peer_head} ≤ {TARGET_SECONDS:g} s |",
        f"|---|---|---|---|---|---|---|---|---|---|---|---|{peer_sep}---|",
    ]
    for env_id, pair in by_game.items():
        ours = pair.get("ours")
        game = env_id.split("/")[-1]
        peer_cells = ""
        for kind in peers_ran:
            peer = pair.get(kind)
            if peer is None or peer.error or peer.total_s is None:
                peer_cells += f" {'failed: ' + peer.error if peer and peer.error else '–'} | – |"
            else:
                speed = ("–" if ours is None or ours.total_s is None
                         else f"{peer.total_s / ours.total_s:.2f}×")
                peer_cells += f" {peer.total_s:.1f} | {speed} |"
        if ours is None or ours.error:
            error = ours.error if ours else "not run"
            lines.append(f"| {game} | failed: {error} |" + " |" * 10 + peer_cells + " – |")
            continue
        lines.append(
            f"| {game} | {ours.decisions:,} | {ours.episodes} | {ours.load_before} "
            f"| {ours.torch_threads} | {_num(ours.states_s)} | {_num(ours.train_s)} "
            f"| {_num(ours.segment_s, '.2f')} | {_num(ours.options_s)} | **{_num(ours.total_s)}** "
            f"| {_num(ours.cpu_s)} | {_num(ours.final_loss, '.3f')} |{peer_cells} "
            f"{verdict(ours, settings, defaults)} |")
    lines += ["", "## Verdicts", ""]
    for env_id, pair in by_game.items():
        ours = pair.get("ours")
        if ours is None or ours.error:
            lines.append(f"- {env_id}: not measured ({ours.error if ours else 'not run'}).")
            continue
        line = (f"- {env_id}: fit in {ours.total_s:.1f} s ({ours.cpu_s:.1f} CPU s); "
                f"{TARGET_SECONDS:g} s target: {verdict(ours, settings, defaults)}")
        loads, codes = [], []
        for kind in peers_ran:
            peer, label = pair.get(kind), PEERS[kind][0]
            if peer is None:
                continue
            loads.append(f"{label}: {peer.load_before}")
            if peer.error or peer.total_s is None:
                line += f"; the {label} failed: {peer.error}"
                continue
            line += (f"; the {label} took {peer.total_s:.1f} s "
                     f"(train {_num(peer.train_s)} s, segment {_num(peer.segment_s, '.2f')} s, "
                     f"options {_num(peer.options_s)} s; {peer.cpu_s:.1f} CPU s): "
                     f"{peer.total_s / ours.total_s:.2f}× as long; final −ELBO "
                     f"{_num(peer.final_loss, '.3f')} against {_num(ours.final_loss, '.3f')}")
            codes.append(f"{label}: {peer.codes}, {peer.segments}")
        lines.append(line + ".")
        lines.append(f"  Load before: {ours.load_before}"
                     + (f" ({'; '.join(loads)})" if loads else "")
                     + f"; codes chosen {ours.codes}, {ours.segments} segments"
                     + (f" ({'; '.join(codes)})" if codes else "") + ".")
    lines += ["", "## Setup", "", f"- Command: `{raw['command']}`"]
    peers = sorted({(r.peer_gru, r.check) for r in results if r.kind == "peer" and r.peer_gru})
    for gru, check in peers:
        lines.append(f"- Peer's GRU: {gru}. Checked before timing: {check}.")
    lines.append("- Worker commands:")
    lines += [f"  - {r.env_id} {r.kind}: `{r.command}`" for r in results]
    lines += ["", "## Machine", ""]
    lines += [f"- {k}: {v}" for k, v in raw["machine"].items()]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", nargs="+", default=list(GAMES), choices=GAMES,
                        metavar="ENV_ID", help=f"games to fit on (default all: {' '.join(GAMES)})")
    parser.add_argument("--iterations", type=int, default=None,
                        help="CompILE's ELBO steps (default: the script's compile_iterations); "
                             "another value is reported as such and not judged")
    parser.add_argument("--torch-threads", type=int, default=0,
                        help="torch threads of the fit (default 0: torch's own, the script's "
                             "default)")
    parser.add_argument("--torch-loop", action=argparse.BooleanOptionalAction, default=True,
                        help="also time the fit with ROUTINE_GYM_COMPILE_GRU=torch, the torch "
                             "loop (default on)")
    parser.add_argument("--peer", action=argparse.BooleanOptionalAction, default=True,
                        help="also time the fit with the GRUCell loop (default on)")
    parser.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "compile_fit.md",
                        help="markdown report; the raw numbers go beside it as .json")
    parser.add_argument("--from-json", type=Path, default=None,
                        help="run nothing: write the report again from this file's raw numbers")
    parser.add_argument("--worker", choices=["ours", "peer"], help=argparse.SUPPRESS)
    parser.add_argument("--worker-env", choices=GAMES, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.iterations is not None and args.iterations < 1:
        parser.error(f"--iterations needs to be ≥ 1, actual value: {args.iterations}")
    if args.torch_threads < 0:
        parser.error(f"--torch-threads needs to be ≥ 0, actual value: {args.torch_threads}")
    if args.worker is not None:
        if args.worker_env is None:
            parser.error("--worker needs --worker-env")
        worker(args)
        return

    from routine_gym.plumbing.atomic import atomic_write_text

    if args.from_json is not None:
        if not args.from_json.is_file():
            parser.error(f"--from-json {args.from_json}: no such file")
        try:
            raw = json.loads(args.from_json.read_text())
            known = {f.name for f in fields(Result)}
            results = [Result(**{k: v for k, v in r.items() if k in known})
                       for r in raw["results"]]
        except (ValueError, KeyError, TypeError) as exc:
            parser.error(f"--from-json {args.from_json}: not this benchmark's raw numbers "
                         f"({exc})")
        args.out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.out, render(results, raw))
        print(f"written to {args.out}")
        return
    missing = [env for env in args.envs if not shipped_demo(env).exists()]
    if missing:
        parser.error(f"no shipped demo for {', '.join(missing)} (looked for "
                     f"{', '.join(str(shipped_demo(e).relative_to(REPO)) for e in missing)})")

    command = "python " + shlex.join([os.path.relpath(__file__, REPO), *sys.argv[1:]])
    settings, defaults = script_settings(args.iterations, args.torch_threads)
    info = machine_info()
    print(f"# {command}\n# load average at start: {load_average()}\n# settings: "
          + ", ".join(f"{k} {v}" for k, v in settings.items()), flush=True)
    results: list[Result] = []
    kinds = [kind for kind, wanted in (("torch-loop", args.torch_loop), ("peer", args.peer))
             if wanted]
    for env_id in dict.fromkeys(args.envs):
        ours = run_worker(env_id, "ours", args)
        peers = [run_worker(env_id, kind, args) for kind in kinds]
        results += [ours, *peers]
        if ours.error:
            line = f"ours FAILED {ours.error}"
        else:
            line = (f"{ours.decisions:,} decisions  load {ours.load_before}  total "
                    f"{ours.total_s:6.1f} s (states {ours.states_s:.1f}, train {ours.train_s:.1f},"
                    f" segment {ours.segment_s:.2f}, options {ours.options_s:.1f})  CPU "
                    f"{ours.cpu_s:.1f} s  {verdict(ours, settings, defaults)}")
        for peer in peers:
            label = PEERS[peer.kind][0]
            if peer.error:
                line += f"  | {label} FAILED {peer.error}"
            else:
                line += f"  | {label} {peer.total_s:.1f} s"
                if not ours.error:
                    line += f" ({peer.total_s / ours.total_s:.2f}×)"
        print(f"{env_id:26s} {line}", flush=True)
    info["load average at end"] = load_average()
    raw = {"command": command, "machine": info, "settings": settings, "defaults": defaults,
           "target_seconds": TARGET_SECONDS, "results": [asdict(r) for r in results]}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out, render(results, raw))
    atomic_write_text(args.out.with_suffix(".json"), json.dumps(raw, indent=2) + "\n")
    print(f"written to {args.out} and {args.out.with_suffix('.json')}")


if __name__ == "__main__":
    from common import children_die_with_me  # no orphan workers after a SIGTERM

    children_die_with_me()
    main()
