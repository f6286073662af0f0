"""CompILE on a demo: fit the ELBO, cut the demo into segments, train the options on them.

`train_compile` fits the ELBO on random windows of the demo's decisions; `segment` cuts the
whole demo into hard segments (`Segmentation`) with the trained model; `fit_options` trains the
decoder and the termination head on those segments; `most_used_codes` picks the codes that
become options. `boundary_scores` measures a segmentation against known boundaries (the tests'
synthetic demos). The budget and the reasons for each step are in the package docstring
(`routine_gym.baselines.compile`).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from routine_gym.baselines.compile.model import CompILE, CompILEConfig
from routine_gym.imitation.agent_view import state_offsets
from routine_gym.plumbing.divergence import check_update

__all__ = [
    "Segmentation",
    "boundary_scores",
    "fit_options",
    "most_used_codes",
    "segment",
    "train_compile",
]


def episode_layout(episode_lengths: Sequence[int] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each episode's decisions and states start in the concatenated arrays."""
    lengths = np.asarray(episode_lengths, dtype=np.int64)
    return np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64), state_offsets(lengths)


def _check_demo_arrays(states: np.ndarray, actions: np.ndarray,
                       episode_lengths: np.ndarray) -> None:
    if int(episode_lengths.sum()) != len(actions):
        raise ValueError(f"the episode lengths add up to {int(episode_lengths.sum())} decisions, "
                         f"but there are {len(actions)} actions")
    if len(states) != len(actions) + len(episode_lengths):
        raise ValueError(
            f"{len(actions)} decisions in {len(episode_lengths)} episode(s) need "
            f"{len(actions) + len(episode_lengths)} states (one before each decision and each "
            f"episode's last), got {len(states)}")
    if episode_lengths.max(initial=0) < 1:
        raise ValueError("the demo has no decision to learn from")


def train_compile(
    states: np.ndarray,
    actions: np.ndarray,
    episode_lengths: Sequence[int] | np.ndarray,
    config: CompILEConfig,
    *,
    iterations: int = 1000,
    batch_size: int = 16,
    learning_rate: float = 1e-3,
    seed: int = 0,
    device: torch.device | str = "cpu",
    log_every: int = 100,
    progress: Callable[[dict[str, float]], None] | None = None,
) -> tuple[CompILE, list[dict[str, float]]]:
    """Fit CompILE's ELBO on random windows of a demo (Adam; see the module docstring).

    Args:
        states: `[Σ_e (D_e + 1), *obs_shape]` the agent's states (`agent_view_states`).
        actions: `[Σ_e D_e]` the decisions (`decision_steps(demo).actions`).
        episode_lengths: `D_e`, the decisions of each episode.
        config: the model; its `window` is cut to the longest episode when that is shorter.
        iterations: gradient steps, one batch of windows each.
        batch_size: windows per batch.
        learning_rate: Adam's.
        seed: initialisation, windows and Gumbel noise (the caller's RNGs are left alone).
        device: where to train.
        log_every: iterations between the log's entries.
        progress: called with each log entry.

    Returns:
        The model (in eval mode) and the log: `iteration`, `loss`, `nll`, `kl_z`, `kl_b`.
    """
    lengths = np.asarray(episode_lengths, dtype=np.int64)
    actions = np.asarray(actions, dtype=np.int64)
    _check_demo_arrays(states, actions, lengths)
    config = CompILEConfig(**{**asdict(config), "window": min(config.window, int(lengths.max()))})
    w = config.window
    decision_start, state_start = episode_layout(lengths)
    # A window lies inside one episode; every start position of every long-enough episode is as
    # likely as any other.
    eligible = np.flatnonzero(lengths >= w)
    starts_per_episode = lengths[eligible] - w + 1
    device = torch.device(device)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model = CompILE(config).to(device)
    generator = torch.Generator(device=device).manual_seed(seed)
    rng = np.random.default_rng(seed)
    states_t = torch.as_tensor(states, device=device)
    actions_t = torch.as_tensor(actions, device=device)
    optimizer = torch.optim.Adam(model.parameters(), lr=learning_rate)
    log: list[dict[str, float]] = []
    model.train()
    for iteration in range(1, iterations + 1):
        pick = rng.choice(len(eligible), size=batch_size, p=starts_per_episode
                          / starts_per_episode.sum())
        episode = eligible[pick]
        offset = rng.integers(0, starts_per_episode[pick])
        steps = offset[:, None] + np.arange(w)[None]  # [B, W] within the episode
        state_index = state_start[episode][:, None] + steps
        # φ once per distinct state of the batch, then gathered into the windows with
        # `index_select`: its backward adds the windows' gradients in a fixed order, where
        # indexing's (`index_put_` with accumulate) adds them in whatever order the CPU's
        # threads finish, and a seeded fit came out differently each time on two threads.
        unique, inverse = np.unique(state_index, return_inverse=True)
        features = model.features(states_t[torch.as_tensor(unique, device=device)])
        features = features.index_select(
            0, torch.as_tensor(inverse.reshape(-1), device=device)
        ).view(*state_index.shape, -1)
        window_actions = actions_t[torch.as_tensor(decision_start[episode][:, None] + steps,
                                                   device=device)]
        recognition = model.recognise(features, window_actions, generator=generator)
        terms = model.negative_elbo(features, window_actions, recognition)
        optimizer.zero_grad()
        terms["loss"].backward()
        grad_norm = nn.utils.clip_grad_norm_(model.parameters(), 10.0)
        check_update(iteration, terms["loss"], grad_norm, unit="CompILE step",
                     parts={f"CompILE {k}": v for k, v in terms.items() if k != "loss"})
        optimizer.step()
        if iteration % log_every == 0 or iteration == iterations:
            entry = {"iteration": iteration, **{k: v.item() for k, v in terms.items()}}
            log.append(entry)
            if progress is not None:
                progress(entry)
    return model.eval(), log


@dataclass(frozen=True)
class Segmentation:
    """A demo cut into hard segments, each with its latent code (see `segment`).

    Attributes:
        episodes: `(S,)` the episode of each segment.
        starts: `(S,)` its first decision, as an index into the concatenated decisions.
        lengths: `(S,)` its decisions.
        codes: `(S,)` its latent code.
    """

    episodes: np.ndarray
    starts: np.ndarray
    lengths: np.ndarray
    codes: np.ndarray

    def __len__(self) -> int:
        return len(self.starts)

    def boundaries(self) -> np.ndarray:
        """Where segments start inside an episode: every start but each episode's first."""
        first = np.concatenate([[True], self.episodes[1:] != self.episodes[:-1]])
        return self.starts[~first]


@torch.no_grad()
def segment(model: CompILE, states: np.ndarray, actions: np.ndarray,
            episode_lengths: Sequence[int] | np.ndarray) -> Segmentation:
    """Cut a whole demo into hard segments: argmax boundaries and codes, window by window.

    Each episode is read in windows of `config.window` decisions: the recognition model's
    segments of a window are kept but the last (its end is the window's cut, not a boundary),
    and the next window starts where that one did; a window that reaches the episode's end
    keeps all its segments, one with no boundary inside is one segment.
    """
    lengths = np.asarray(episode_lengths, dtype=np.int64)
    actions = np.asarray(actions, dtype=np.int64)
    _check_demo_arrays(states, actions, lengths)
    device = next(model.parameters()).device
    was_training = model.training
    model.eval()
    decision_start, state_start = episode_layout(lengths)
    w = model.config.window
    out: dict[str, list[int]] = {"episodes": [], "starts": [], "lengths": [], "codes": []}
    for e, d in enumerate(lengths):
        position = 0
        features = model.features(torch.as_tensor(
            states[state_start[e]: state_start[e] + d], device=device))
        episode_actions = torch.as_tensor(actions[decision_start[e]: decision_start[e] + d],
                                          device=device)
        while position < d:
            end = min(position + w, int(d))
            rec = model.recognise(features[None, position:end],
                                  episode_actions[None, position:end], hard=True)
            cuts = [0] + rec.boundaries[:, 0].argmax(dim=-1).tolist()
            codes = rec.latents[:, 0].argmax(dim=-1).tolist()
            pieces = [(cuts[m], cuts[m + 1], codes[m]) for m in range(len(codes))
                      if cuts[m + 1] > cuts[m]]
            if end < d and len(pieces) > 1:
                pieces = pieces[:-1]
            for a, b, code in pieces:
                out["episodes"].append(e)
                out["starts"].append(int(decision_start[e]) + position + a)
                out["lengths"].append(b - a)
                out["codes"].append(code)
            position += pieces[-1][1]
    model.train(was_training)
    return Segmentation(**{k: np.asarray(v, dtype=np.int64) for k, v in out.items()})


def _segment_steps(segmentation: Segmentation,
                   episode_lengths: np.ndarray) -> dict[str, np.ndarray]:
    """Per decision of the segmented demo: its state, next state, code and termination target."""
    decision_start, state_start = episode_layout(episode_lengths)
    rows: dict[str, list] = {"state": [], "next_state": [], "decision": [], "code": [],
                             "ends": [], "valid": []}
    for e, start, length, code in zip(segmentation.episodes, segmentation.starts,
                                      segmentation.lengths, segmentation.codes, strict=True):
        local = start - decision_start[e]
        for j in range(length):
            t = local + j
            rows["state"].append(state_start[e] + t)
            rows["next_state"].append(state_start[e] + t + 1)
            rows["decision"].append(start + j)
            rows["code"].append(code)
            last = j == length - 1
            rows["ends"].append(last)
            # A segment that the episode's end cut says nothing about when the skill ends.
            rows["valid"].append(not (last and t + 1 == episode_lengths[e]))
    return {k: np.asarray(v) for k, v in rows.items()}


def fit_options(
    model: CompILE,
    states: np.ndarray,
    actions: np.ndarray,
    episode_lengths: Sequence[int] | np.ndarray,
    segmentation: Segmentation,
    *,
    steps: int = 500,
    batch_size: int = 256,
    learning_rate: float = 1e-3,
    seed: int = 0,
) -> list[dict[str, float]]:
    """Train the decoder and the termination head on the hard segments (supervised).

    For step `t` of a segment with code `c`: cross-entropy of `π(· | s_t, z_c)` against the
    demo's action, and binary cross-entropy of `β(s_{t+1}, z_c)` against "t is the segment's
    last step" (left out where the episode's end cut the segment). Trains the model in place;
    returns a log of `step`, `policy_loss`, `termination_loss`.
    """
    lengths = np.asarray(episode_lengths, dtype=np.int64)
    data = _segment_steps(segmentation, lengths)
    device = next(model.parameters()).device
    rng = np.random.default_rng(seed)
    states_t = torch.as_tensor(states, device=device)
    actions_t = torch.as_tensor(np.asarray(actions, dtype=np.int64), device=device)
    eye = torch.eye(model.config.num_latents, device=device)
    optimizer = torch.optim.Adam(model.parameters(), lr=learning_rate)
    log = []
    model.train()
    for step in range(1, steps + 1):
        pick = rng.choice(len(data["state"]), size=min(batch_size, len(data["state"])),
                          replace=False)
        z = eye[torch.as_tensor(data["code"][pick], device=device)]
        both = model.features(states_t[torch.as_tensor(
            np.concatenate([data["state"][pick], data["next_state"][pick]]), device=device)])
        here, after = both[: len(pick)], both[len(pick):]
        policy_loss = F.cross_entropy(
            model.policy_logits(here, z),
            actions_t[torch.as_tensor(data["decision"][pick], device=device)])
        valid = torch.as_tensor(data["valid"][pick], device=device, dtype=torch.float32)
        bce = F.binary_cross_entropy_with_logits(
            model.termination_logits(after, z),
            torch.as_tensor(data["ends"][pick], device=device, dtype=torch.float32),
            reduction="none")
        termination_loss = (bce * valid).sum() / valid.sum().clamp(min=1.0)
        loss = policy_loss + termination_loss
        optimizer.zero_grad()
        loss.backward()
        grad_norm = nn.utils.clip_grad_norm_(model.parameters(), 10.0)
        check_update(step, loss, grad_norm, unit="CompILE option step", parts={
            "option policy loss": policy_loss, "termination loss": termination_loss})
        optimizer.step()
        if step % 100 == 0 or step == steps:
            log.append({"step": step, "policy_loss": policy_loss.item(),
                        "termination_loss": termination_loss.item()})
    model.eval()
    return log


def most_used_codes(segmentation: Segmentation, k: int) -> list[int]:
    """The `k` codes with the most segments (ties: more decisions, then the lower code).

    Fewer when fewer codes are used.

    Example:
        >>> s = Segmentation(episodes=np.zeros(5, int), starts=np.arange(5),
        ...                  lengths=np.array([1, 3, 2, 2, 1]), codes=np.array([4, 1, 4, 2, 1]))
        >>> most_used_codes(s, 2)  # codes 4 and 1 have 2 segments each; 1 has 4 decisions
        [1, 4]
    """
    counts = Counter(segmentation.codes.tolist())
    steps = Counter()
    for code, length in zip(segmentation.codes.tolist(), segmentation.lengths.tolist(),
                            strict=True):
        steps[code] += length
    return sorted(counts, key=lambda c: (-counts[c], -steps[c], c))[:k]


def boundary_scores(predicted: Sequence[int] | np.ndarray, true: Sequence[int] | np.ndarray,
                    tolerance: int = 0) -> tuple[float, float]:
    """Boundary precision and recall, a predicted boundary matching a true one within
    `tolerance` steps (each true boundary matched at most once, nearest first).

    Example:
        >>> boundary_scores([3, 7, 9], [3, 6, 12], tolerance=1)  # 3 and 7 match 3 and 6
        (0.6666666666666666, 0.6666666666666666)
        >>> boundary_scores([3, 7, 9], [3, 6, 12])
        (0.3333333333333333, 0.3333333333333333)
    """
    predicted, true = np.asarray(predicted), np.asarray(true)
    if len(predicted) == 0 or len(true) == 0:
        return 0.0, 0.0
    distance = np.abs(predicted[:, None] - true[None, :])
    matched_true: set[int] = set()
    matches = 0
    for i in np.argsort(distance.min(axis=1), kind="stable"):
        for j in np.argsort(distance[i], kind="stable"):
            if distance[i, j] > tolerance:
                break
            if j not in matched_true:
                matched_true.add(int(j))
                matches += 1
                break
    return matches / len(predicted), matches / len(true)
