"""Imitation learning from one demonstration: the pieces `algos/rapl_sqil.py`, `algos/bc.py`
and `algos/gail.py` share (SPEC §5–6), a module each.

- `agent_view`: the demo's states as the agent saw them at the demonstrator's decisions
  (`agent_view_states`, `decision_steps`, `state_offsets`).
- `demo_buffer`: RAPL-SQIL's demo buffer `D_prim ∪ D_routine` (`build_demo_transitions`) and
  the (state, action) pairs of BC and GAIL (`demo_pairs`).
- `soft_q`: SQIL's soft target `R_sq + Γ·α·logsumexp(Q(s', ·)/α)` (`sqil_target`).

The agent's replay memory is `routine_gym.replay_memory.FrameReplayMemory`; loading the demo
and the routines is `routine_gym.plumbing.loading`; the evaluation all scripts share is
`routine_gym.plumbing.evaluation`.
"""

from routine_gym.imitation.agent_view import (
    DecisionSteps,
    agent_view_states,
    decision_steps,
    state_offsets,
)
from routine_gym.imitation.demo_buffer import (
    DemoPairs,
    DemoTransitions,
    build_demo_transitions,
    demo_pairs,
    primitive_transitions,
    routine_transitions,
)
from routine_gym.imitation.soft_q import soft_value, sqil_reward_and_discount, sqil_target
from routine_gym.replay_memory import FrameReplayMemory

__all__ = [
    "DecisionSteps",
    "DemoPairs",
    "DemoTransitions",
    "FrameReplayMemory",
    "agent_view_states",
    "build_demo_transitions",
    "decision_steps",
    "demo_pairs",
    "primitive_transitions",
    "routine_transitions",
    "soft_value",
    "sqil_reward_and_discount",
    "sqil_target",
    "state_offsets",
]
