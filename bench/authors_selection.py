"""Our `selection="authors"` against the authors' own code, on every shipped demo.

    python bench/authors_selection.py                 # ours only: paper vs authors libraries
    python bench/authors_selection.py --authors-python /tmp/authors_venv/bin/python \\
        --authors-dir /tmp/authors_rapl --shim-dir /tmp/authors_shims

Loads each demo with `routine_gym.demo.Demo` and mines K = 3 routines (α = 2, the defaults of
`algos/rapl_a2c.py`) with the paper's selection, the authors' selection, and the authors'
selection without their missed last occurrence (to show what copying it changes). With
`--authors-python`, runs `bench/authors_code_runner.py` under that interpreter on the demos of
one decision segment (their code takes one sequence) and compares: their selection on our
Sequitur's candidates, and their whole pipeline (their Sequitur port, then their selection).
`bench/results/authors_selection.md` says how their code was extracted. Prints markdown.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path
from unittest import mock

from routine_gym.demo import Demo
from routine_gym.mining import SequiturMiner, _Selector

REPO = Path(__file__).resolve().parent.parent
K, ALPHA = 3, 2


def _mine(demo: Demo, selection: str, miss_last: bool = True) -> dict[str, list]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if miss_last:
            library = SequiturMiner(K, alpha=ALPHA, selection=selection).mine(demo)
        else:
            with mock.patch.object(_Selector, "_ends_the_input", lambda self, routine: False):
                library = SequiturMiner(K, alpha=ALPHA, selection=selection).mine(demo)
    return {"routines": [list(r) for r in library.routines],
            "frequencies": list(library.frequencies), "scores": list(library.scores)}


def _show(library: dict) -> str:
    return " ".join("[" + ",".join(map(str, r)) + f"]×{f}"
                    for r, f in zip(library["routines"], library["frequencies"], strict=True))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--authors-python", help="an interpreter with numpy and Levenshtein")
    parser.add_argument("--authors-dir", help="their repository's files, extracted")
    parser.add_argument("--shim-dir", help="a folder holding the one-line torch stub")
    args = parser.parse_args()

    rows, single = {}, {}
    for path in sorted((REPO / "demos").glob("*.npz")):
        demo = Demo.load(path)
        segments, _ = demo.decision_segments()
        name = path.name
        rows[name] = {
            "segments": len(segments),
            "paper": _mine(demo, "paper"),
            "authors": _mine(demo, "authors"),
            "authors_no_miss": _mine(demo, "authors", miss_last=False),
        }
        if len(segments) == 1:
            actions = [int(a) for a in segments[0]]
            candidates = SequiturMiner(K, alpha=ALPHA).candidates([segments[0]])
            single[name] = {"actions": actions, "num_actions": demo.num_actions,
                            "candidates": [list(c) for c in candidates]}

    print("| demo | segments | paper | authors (ours) "
          "| what copying the missed last occurrence changes |")
    print("|---|---|---|---|---|")
    for name, row in rows.items():
        with_miss, without = row["authors"], row["authors_no_miss"]
        changed = next((f"{what}; without it {_show(without)}" for what, key in (
            ("routines", "routines"), ("frequencies", "frequencies"), ("scores only", "scores"))
            if with_miss[key] != without[key]), "no")
        print(f"| {name} | {row['segments']} | {_show(row['paper'])} | "
              f"{_show(row['authors'])} | {changed} |")

    if not args.authors_python:
        return
    with tempfile.TemporaryDirectory() as tmp:
        path_in, path_out = Path(tmp) / "in.json", Path(tmp) / "out.json"
        path_in.write_text(json.dumps(single))
        runner = Path(__file__).with_name("authors_code_runner.py")
        subprocess.run([args.authors_python, str(runner), args.authors_dir, args.shim_dir,
                        str(path_in), str(path_out), str(K), str(ALPHA)], check=True)
        theirs = json.loads(path_out.read_text())
    print()
    print("| demo | ours, authors | theirs on our candidates | identical (routines, f, scores) "
          "| theirs, whole pipeline | their candidates = ours |")
    print("|---|---|---|---|---|---|")
    for name, t in theirs.items():
        ours = rows[name]["authors"]
        same = ours == t["on_ours"]
        same_candidates = t["grammar_candidates"] == single[name]["candidates"]
        print(f"| {name} | {_show(ours)} | {_show(t['on_ours'])} | {'yes' if same else 'NO'} | "
              f"{_show(t['full'])} | {'yes' if same_candidates else 'no'} "
              f"({len(t['grammar_candidates'])} vs {len(single[name]['candidates'])}) |")
    sys.stdout.flush()


if __name__ == "__main__":
    from common import children_die_with_me  # no orphan workers after a SIGTERM

    children_die_with_me()
    main()
