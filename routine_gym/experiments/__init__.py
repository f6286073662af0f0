"""The paper's six experiments (SPEC §8)."""
