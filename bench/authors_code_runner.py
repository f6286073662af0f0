"""Run the authors' routine selection, their code unchanged, on action sequences we give it.

Not a routine_gym module: it runs under a scratch interpreter that has their dependencies
(numpy, Levenshtein), with their repository's files extracted to AUTHORS_DIR (see
`bench/authors_selection.py`). `utils/tensor_list.py` imports torch for a function the selection
never calls, so a one-line stub module stands in for it (SHIM_DIR).

    python authors_code_runner.py AUTHORS_DIR SHIM_DIR IN.json OUT.json K ALPHA

IN.json: {name: {"actions": [...], "num_actions": n, "candidates": [[...], ...]}}.
OUT.json, per name: "full": `CmSqRtProposal(actions, n).run(similar_thre=ALPHA, select_num=K)`
as their `test_a2c_and_abstract_routine.py:220-221` calls it (their Sequitur and their
selection), with "grammar_candidates", the rules their `run_sequitur` collects; "on_ours": their
`evaluate_routines` on our candidates, set where `run_sequitur` sets them.
"""

import contextlib
import io
import json
import sys


def main() -> None:
    authors_dir, shim_dir, path_in, path_out, k, alpha = sys.argv[1:7]
    sys.path[:0] = [shim_dir, authors_dir]
    from make_demo_discover_rt.sq_rt_proposal import CmSqRtProposal

    k, alpha = int(k), int(alpha)
    out = {}
    for name, demo in json.load(open(path_in)).items():
        actions, n = [int(a) for a in demo["actions"]], int(demo["num_actions"])
        with contextlib.redirect_stdout(io.StringIO()):
            grammar = CmSqRtProposal(actions, prim_num=n)
            grammar.run_sequitur()
            full = CmSqRtProposal(actions, prim_num=n)
            full.run(similar_thre=alpha, select_num=k)
            on_ours = CmSqRtProposal(actions, prim_num=n)
            on_ours.rt_actions_idxs = [list(c) for c in demo["candidates"]]
            on_ours.evaluate_routines(similar_thre=alpha, select_num=k)
        out[name] = {
            "grammar_candidates": [list(c) for c in grammar.rt_actions_idxs],
            **{
                key: {
                    "routines": [list(r) for r in prop.rt_actions_idxs],
                    "frequencies": [int(f) for f in prop.rt_frequencies],
                    "scores": [float(s) for s in prop.rt_scores],
                }
                for key, prop in (("full", full), ("on_ours", on_ours))
            },
        }
    with open(path_out, "w") as f:
        json.dump(out, f)


if __name__ == "__main__":
    main()
