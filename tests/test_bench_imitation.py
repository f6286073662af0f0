"""`bench/bench_imitation.py` run as a user runs it, with a tiny budget: two seeds of BC on
MiniQbert give a report row whose alignment, score and episode length are the mean ± sample std
of the two runs' eval.json files (worked out here from them), each seed's alignment, and the
paper's BC numbers; bad input is refused with a one-line error before any run starts."""

from __future__ import annotations

import json
from functools import partial
from statistics import mean, stdev

from bench_runner import run_bench

run = partial(run_bench, "bench_imitation.py")  # the script as a user runs it


def test_two_seeds_of_bc_give_the_mean_and_sample_std_of_their_eval_files(tmp_path):
    runs, out = tmp_path / "runs", tmp_path / "imitation.md"
    done = run("--methods", "BC", "--seeds", 1, 2, "--bc-steps", 5, "--eval-episodes", 1,
               "--jobs", 1, "--run-dir", runs, "--out", out, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    results = [json.loads(next((runs / "MiniQbert-v0" / "BC" / f"seed{seed}").glob(
        "*/eval.json")).read_text()) for seed in (1, 2)]
    assert all(r["global_step"] == 5 and r["episodes"] == 1 for r in results)
    report = out.read_text()
    assert report in done.stdout  # the report is also printed
    demo = results[0]
    assert (f"Demo: the shipped demo (score {demo['demo_score']:g}, {demo['demo_length']} "
            "actions). Budgets: BC 5 gradient steps") in report
    assert "; 1 evaluation episodes per run." in report

    def mean_std(values, fmt):
        return f"{mean(values):{fmt}} ± {stdev(values):{fmt}}"

    alignments = [r["mean_alignment"] for r in results]
    (line,) = [line for line in report.splitlines() if line.startswith("| BC |")]
    cells = [cell.strip() for cell in line.strip("|").split("|")]
    raw = json.loads(out.with_suffix(".json").read_text())
    assert cells == [
        "BC", mean_std(alignments, ".3f"), mean_std([r["mean_return"] for r in results], ".1f"),
        mean_std([mean(r["lengths"]) for r in results], ".0f"), "0.18 / 18.3 %",
        ", ".join(f"{a:.3f}" for a in alignments),
        f"{mean(r['wall_s'] for r in raw['runs']):.0f} s"]
    for seed, a in zip((1, 2), alignments, strict=True):
        assert f"MiniQbert-v0 BC seed {seed}: alignment {a:.3f}" in done.stdout
    assert (f"- BC: `python algos/bc.py --env-id MiniQbert-v0 --seed 1 --gradient-steps 5 "
            f"--eval-episodes 1 --run-dir {runs}/MiniQbert-v0/BC/seed1`") in report
    assert [(r["seed"], r["alignment"], r["score"]) for r in raw["runs"]] == [
        (s, r["mean_alignment"], r["mean_return"]) for s, r in zip((1, 2), results, strict=True)]
    assert "FAILED" not in report


def test_bad_input_is_refused_in_one_line(tmp_path):
    used = tmp_path / "used"
    (used / "MiniQbert-v0" / "BC" / "seed1" / "run").mkdir(parents=True)
    (used / "MiniQbert-v0" / "BC" / "seed1" / "run" / "eval.json").write_text("{}")
    for words, message in [
        (("--steps", "-1"), "--steps needs to be ≥ 0, actual value: -1"),
        (("--bc-steps", "0"), "--bc-steps needs to be ≥ 1, actual value: 0"),
        (("--gail-steps", "0"), "--gail-steps needs to be ≥ 1, actual value: 0"),
        (("--eval-episodes", "0"), "--eval-episodes needs to be ≥ 1, actual value: 0"),
        (("--jobs", "0"), "--jobs needs to be ≥ 1, actual value: 0"),
        (("--temperatures", "1", "0"), "--temperatures need to be > 0, actual value: [1.0, 0.0]"),
        (("--steps", "0"), "nothing to run: --steps and --atari-steps are both 0"),
        (("--seeds", "1", "2", "1"), "--seeds names a seed twice: 1 2 1"),
        (("--run-dir", used), f"--run-dir {used} already holds runs (eval.json): give an empty "
                              "or new folder"),
    ]:
        done = run(*words, "--out", tmp_path / "out.md", cwd=tmp_path)
        assert done.returncode == 2, (words, done.stderr[-2000:])
        assert "Traceback" not in done.stderr
        assert done.stderr.strip().splitlines()[-1] == f"bench_imitation.py: error: {message}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["used"]  # no report written
