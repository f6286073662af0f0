"""CompILE (Kipf et al. 2019) on one demo, and its latent codes as options.

CompILE ("Compositional Imitation Learning and Execution") segments a demonstration into `M`
segments with one latent code each by maximising an ELBO: a recognition model places the
boundaries `b_0 < b_1 < … < b_{M-1}` (Gumbel-softmax / concrete relaxations of a categorical
over positions) and reads a latent `z_m` out of each segment; a decoder `π(a | s, z)`
reconstructs every segment's actions from its states and its latent. The package, in the order
a run uses it:

- `elbo.py`: the ELBO's terms as pure functions with hand-worked tests
  (`tests/test_compile.py`).
- `model.py`: `CompILEConfig`, the `CompILE` networks, and the model's file.
- `training.py`: `train_compile` (the ELBO on a demo), `segment` (the demo cut into hard
  segments), `fit_options` (decoder and termination head on them), `most_used_codes`.
- `options.py`: `CompILEOptions`, `OptionActionWrapper` (the codes as macro-actions, with the
  `info` of `routine_gym.macro_info`) and `option_primitive_policy` (for evaluation).
- `summary.py`: what each option did in the demo, as `algos/compile_a2c.py` prints it.

The public names are importable from the package itself
(`from routine_gym.baselines.compile import train_compile`).

The reference code (github.com/tkipf/compile) is a toy on symbol sequences; the choices made
here for RL demos, and why:

- **Data.** The demo's decisions (`decision_steps`: the steps the demonstrator chose, the
  injected no-ops and FIREs left out) and the states the agent saw at them
  (`agent_view_states`: replayed from the demo's seeds through the agent's observation
  pipeline). One demo is one long sequence, so training samples `batch_size` windows of
  `window` = 32 consecutive decisions inside an episode at random offsets; each window is
  segmented into `num_segments` = M = 10 segments. Windows are short enough for a recurrent
  recognition model and long enough for several skills: 32 / λ = 8 segments of the prior's
  mean length, and M leaves room for the partial segments at the window's two cuts (the
  segments after the one that reaches the window's end are empty and cost nothing).
- **Networks.** One state encoder φ, the env family's torso (`ObservationEncoder`: Nature CNN
  on Atari, IMPALA CNN on Procgen, MinAtar's network, an MLP for flat observations), shared by
  recognition, decoder and termination head. Recognition: `x_t = ReLU(W φ(s_t) + E a_t)` with a
  learned end-of-window vector appended, a GRU (128 units) re-run once per segment with its
  state multiplied by the soft mask of positions past the previous boundaries (the reference's
  masked LSTM: it starts afresh at each boundary), a boundary head (logit per position) and a
  latent head (read out at the segment's last step). Decoder and termination head: MLPs on
  `[φ(s), z]` (128 units).
- **Latent: concrete (Gumbel-softmax) over `num_latents` = 8 codes**, uniform prior. A discrete
  code makes "K latents become options" direct: each code *is* an option, `z_k` its one-hot,
  with no clustering of continuous latents (the reference's other choice, Gaussian); the K most
  used codes of the demo's segmentation become the options, as RAPL keeps its K most frequent
  routines.
- **Prior on lengths: Poisson(λ = 4)**, normalised over the lengths a boundary can still take
  in the window (the routines of RAPL's demos are 3–8 actions long). Unlike the reference code,
  which scores only the first segment's boundary (times M, and one position off), each
  boundary's KL is taken against the prior on its own segment's length, counted from the
  previous boundary (its hard position); positions the prior rules out count as probability
  `EPS`, so a relaxed boundary cannot park its mass there for free. Both KLs are weighted
  β_b = β_z = 0.1 and both temperatures are 1, as in the reference code.
- **Budget** (`train_compile`): 1000 Adam steps (lr 1e-3, gradient norm clipped at 10) of 16
  windows, then (`fit_options`) 500 steps of 256 decisions. φ runs once per distinct state of
  a batch, so a step costs at most `batch_size · window` encoder passes.
- **Options.** After the ELBO, `segment` cuts the whole demo into hard segments (argmax
  boundaries and codes, window by window), and `fit_options` trains the decoder and a
  termination head `β(s', z)` by supervised learning on them: `β` is 1 on the state after a
  segment's last step, 0 on the states after its other steps (segment ends made by the end of
  the episode are left out: the episode, not the skill, ended them).

`CompILEOptions` holds the K codes with the decoder and the termination head on the CPU, and
`OptionActionWrapper` adds them to an env as `Discrete(n + K)`: option `k` runs the decoder's
greedy action `argmax_a π(a | s, z_k)` one primitive step at a time until the termination head
fires on the state reached (`β(s', z_k) > 0.5`), `max_length` steps have run, or the episode
ends. Greedy, because the options then need no random state of their own (nothing to seed or
checkpoint) and do what the demo did; the env's own randomness (sticky actions) remains.

A decoder that sees the state reconstructs a short, deterministic demo nearly without the
latent (posterior collapse): on MiniQbert's 39 decisions the latents' KL stays about 0.02
nats, so the codes say little and the boundaries mostly follow the prior. The options are then
the decoder's imitation of the demo, run for about λ steps (there: segments of 2–5 decisions,
the decoder 100 % accurate on them). That is CompILE's own behaviour with a strong decoder,
kept as it is for the baseline.
"""

from routine_gym.baselines.compile.elbo import (
    boundary_mask,
    kl_boundary,
    kl_latent_uniform,
    poisson_length_log_prior,
    reconstruction_nll,
    segment_probabilities,
)
from routine_gym.baselines.compile.masked_gru import gru_choice
from routine_gym.baselines.compile.model import (
    CompILE,
    CompILEConfig,
    compile_from_state,
    compile_state,
    load_compile,
    save_compile,
)
from routine_gym.baselines.compile.options import (
    CompILEOptions,
    OptionActionWrapper,
    option_primitive_policy,
)
from routine_gym.baselines.compile.summary import OptionSummary, describe_options, option_summary
from routine_gym.baselines.compile.training import (
    Segmentation,
    boundary_scores,
    fit_options,
    most_used_codes,
    segment,
    train_compile,
)

__all__ = [
    "CompILE",
    "CompILEConfig",
    "CompILEOptions",
    "OptionActionWrapper",
    "OptionSummary",
    "Segmentation",
    "boundary_mask",
    "boundary_scores",
    "compile_from_state",
    "compile_state",
    "describe_options",
    "fit_options",
    "gru_choice",
    "kl_boundary",
    "kl_latent_uniform",
    "load_compile",
    "most_used_codes",
    "option_primitive_policy",
    "option_summary",
    "poisson_length_log_prior",
    "reconstruction_nll",
    "save_compile",
    "segment",
    "segment_probabilities",
    "train_compile",
]
