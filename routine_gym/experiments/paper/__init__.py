"""The paper's six experiments (SPEC §6, §8), one `Experiment` per module, each registered by
one line in `routine_gym.experiments.registry`."""
