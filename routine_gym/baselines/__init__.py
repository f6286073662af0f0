"""The paper's option baselines, which RAPL is compared with: what their scripts in `algos/`
import, apart from what every script shares.

- `compile/`: CompILE (Kipf et al. 2019): options learnt from the one demo (the model, its
  training and segmentation, and `OptionActionWrapper`, which adds the options to an env);
  `algos/compile_a2c.py` trains an A2C controller over them.
- `option_critic.py`: the mathematics of the option-critic (A2OC: Harb et al. 2018, Bacon et
  al. 2017) as pure functions; `algos/option_critic.py` is the rest.

Importing this package imports neither (nor torch).
"""
