"""What CompILE's options did in the demo: their segments, actions and decoder accuracy
(`option_summary`, which `algos/compile_a2c.py` keeps in the model's meta), and a readable
table of them (`describe_options`, which it prints).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from routine_gym.baselines.compile.model import CompILE
from routine_gym.baselines.compile.training import Segmentation, episode_layout
from routine_gym.library import routine_name

__all__ = ["OptionSummary", "describe_options", "option_summary"]


@dataclass
class OptionSummary:
    """What one option did in the demo's segmentation (`option_summary`)."""

    code: int
    segments: int
    min_length: int
    mean_length: float
    max_length: int
    demo_actions: list[tuple[str, int]] = field(default_factory=list)
    """the most frequent action sequences of its segments in the demo, with their counts"""
    decoded_actions: list[tuple[str, int]] = field(default_factory=list)
    """the most frequent greedy decodings `argmax π(a | s_t, z)` of its segments' states"""
    decoder_accuracy: float = 0.0
    """how often the greedy decoding is the demo's action on its segments"""


@torch.no_grad()
def option_summary(model: CompILE, states: np.ndarray, actions: np.ndarray,
                   segmentation: Segmentation, episode_lengths: Sequence[int] | np.ndarray,
                   codes: Sequence[int], meanings: Sequence[str] | None = None,
                   top: int = 3) -> list[OptionSummary]:
    """How long each code's segments were and which actions they hold and decode to."""
    lengths = np.asarray(episode_lengths, dtype=np.int64)
    _, state_start = episode_layout(lengths)
    decision_start, _ = episode_layout(lengths)
    device = next(model.parameters()).device
    eye = torch.eye(model.config.num_latents, device=device)
    out = []
    for code in codes:
        chosen = np.flatnonzero(segmentation.codes == code)
        demo_strings, decoded_strings, correct, total = Counter(), Counter(), 0, 0
        for s in chosen:
            e, start, length = (segmentation.episodes[s], segmentation.starts[s],
                                segmentation.lengths[s])
            first_state = state_start[e] + start - decision_start[e]
            features = model.features(torch.as_tensor(
                states[first_state: first_state + length], device=device))
            decoded = model.policy_logits(features, eye[code].expand(length, -1)) \
                .argmax(dim=-1).cpu().numpy()
            demo = actions[start: start + length]
            demo_strings[routine_name(demo.tolist(), meanings)] += 1
            decoded_strings[routine_name(decoded.tolist(), meanings)] += 1
            correct += int((decoded == demo).sum())
            total += int(length)
        seg_lengths = segmentation.lengths[chosen]
        out.append(OptionSummary(
            code=int(code), segments=len(chosen),
            min_length=int(seg_lengths.min()) if len(chosen) else 0,
            mean_length=float(seg_lengths.mean()) if len(chosen) else 0.0,
            max_length=int(seg_lengths.max()) if len(chosen) else 0,
            demo_actions=demo_strings.most_common(top),
            decoded_actions=decoded_strings.most_common(top),
            decoder_accuracy=correct / max(total, 1)))
    return out


def describe_options(summaries: Sequence[OptionSummary], max_length: int) -> str:
    """A readable table of `option_summary`."""
    lines = [f"{len(summaries)} CompILE option(s), each runs at most {max_length} steps:"]
    for k, s in enumerate(summaries):
        lines.append(
            f"  O{k} = z{s.code}: {s.segments} segments of {s.min_length}–{s.max_length} "
            f"(mean {s.mean_length:.1f}) decisions; decoder accuracy {s.decoder_accuracy:.0%}")
        lines.append("      demo:    " + ", ".join(f"{a} ×{c}" for a, c in s.demo_actions))
        lines.append("      decoded: " + ", ".join(f"{a} ×{c}" for a, c in s.decoded_actions))
    return "\n".join(lines)
