"""The env seeds of a run's training, evaluation and demo episodes (`--seed-stride`).

A run with experiment seed `s` resets its `E` training envs with the seeds `b, b + 1, …,
b + E − 1` (Gymnasium's vector reset), evaluates on episodes reset with `e, e + 1, …` and
records its demo from episodes reset with `d, d + 1, …`:

- `--seed-stride 1` (the default, every committed run): `b = s`, `e = s + 10,000`,
  `d = s + 20,000`. Seeds 1, 2 and 3 of an experiment then share 14 of their 16 training env
  seeds and 29 of their 30 evaluation episodes.
- `--seed-stride S` (S ≥ 4): run `s` owns the block `[s·S, (s + 1)·S)`: training envs from
  `s·S`, evaluation episodes from `s·S + S/2`, demo episodes from `s·S + 3S/4`. No two
  experiment seeds share an env seed as long as `E ≤ S/2` and at most `S/4` evaluation and demo
  episodes each (`stride_checks`).

A resumed run resets its envs with other seeds than the first leg (so it does not replay the
episodes it saw): `b + global_step` with stride 1; with a stride, a seed drawn from
`SeedSequence((s, global_step))` in `[2^31, 2^32)`, above every block (blocks end below 2^31).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["demo_seed", "eval_seed", "stride_checks", "train_seed"]

#: Stride 1's offsets of the evaluation and demo episodes (the scripts' seeds before the flag).
EVAL_OFFSET, DEMO_OFFSET = 10_000, 20_000
#: Every stride block ends below this; a resumed leg's seeds are drawn above it.
BLOCKS_END = 2**31


def train_seed(seed: int, stride: int = 1, global_step: int = 0) -> int:
    """The seed of training env 0 (env i: this + i) at `global_step` (0: a new run).

    Example:
        >>> train_seed(3), train_seed(3, 1, 500), train_seed(3, 1000)
        (3, 503, 3000)
        >>> 2**31 <= train_seed(3, 1000, 500) < 2**32
        True
    """
    if stride == 1:
        return seed + global_step
    if global_step == 0:
        return seed * stride
    draw = np.random.SeedSequence((seed, global_step)).generate_state(1, np.uint32)[0]
    return BLOCKS_END + int(draw) % (2**32 - BLOCKS_END - 2**16)  # room for the envs' + i


def eval_seed(seed: int, stride: int = 1) -> int:
    """The reset seed of the first evaluation episode (episode k: this + k).

    Example:
        >>> eval_seed(3), eval_seed(3, 1000)
        (10003, 3500)
    """
    return seed + EVAL_OFFSET if stride == 1 else seed * stride + stride // 2


def demo_seed(seed: int, stride: int = 1) -> int:
    """The reset seed of the first episode `--record-demo` picks from (episode k: this + k).

    Example:
        >>> demo_seed(3), demo_seed(3, 1000)
        (20003, 3750)
    """
    return seed + DEMO_OFFSET if stride == 1 else seed * stride + 3 * stride // 4


def stride_checks(args: Any) -> list[tuple[str, bool, str]]:
    """The rules that keep `--seed-stride`'s blocks apart (none with stride 1), as
    `check_args`'s extra checks: the training envs fit in half a block, the evaluation and
    demo episodes in a quarter each, and the run's block ends below 2^31."""
    stride = getattr(args, "seed_stride", 1)
    if stride == 1:
        return []
    rules = [("seed_stride", stride >= 4, "1 (the old seeds) or ≥ 4"),
             ("seed_stride", (args.seed + 1) * stride <= BLOCKS_END,
              f"≤ 2^31 / (--seed + 1) = {BLOCKS_END // (args.seed + 1):,} (the run's seed "
              "block must end below 2^31)"),
             ("seed_stride", getattr(args, "num_envs", 1) <= stride // 2,
              f"≥ 2 × --num-envs ({2 * getattr(args, 'num_envs', 1)}): the training envs "
              "take half of a run's seed block")]
    for flag in ("eval_episodes", "demo_episodes"):
        episodes = getattr(args, flag, 0)
        rules.append(("seed_stride", episodes <= stride // 4,
                      f"≥ 4 × --{flag.replace('_', '-')} ({4 * episodes}): its episodes take "
                      "a quarter of a run's seed block"))
    return rules
