"""The plumbing every script in `algos/` and every `routine-gym` command shares; none of it is
the paper's.

The paper's pieces (the grammar, the mining, the routine library, the wrapper, the returns,
the metrics) sit at the top of `routine_gym/`, each in a module named for it. What lies here
carries a run from its flags to its files and is the same whatever the algorithm:

- `run`: a run's set-up (argument checks, `--resume`, the run folder, seeding, the writer).
- `loading`: the demo and the routines of a run.
- `evaluation`: the one evaluation of every script and its `eval.json`.
- `checkpoint` and `rng`: resumable checkpoints and the generators' state they hold.

Two pieces it leans on sit below it, at the top of `routine_gym/`, because the library, the demo
formats and the videos need them too: `routine_gym.atomic`, the one writer of every file (never
half a file on disk), and `routine_gym.errors`, a user's mistakes and how they are reported.

It is called plumbing because that is what it is: pipes between the paper's pieces and the
disk, the command line and the user, that a reader of the paper need not open. Importing the
package imports none of its modules (so none of torch, ALE or Procgen).
"""
