"""`bench/bench_baselines.py` run as a user runs it: one tiny A2C run on MinAtar Breakout gives
a report row holding its eval.json's return, and a second invocation skips the finished run;
`--report-only` over hand-made eval.json files prints the mean ± sample std over seeds worked
out by hand and the seeds still missing; bad input is refused with a one-line error."""

from __future__ import annotations

import json
from functools import partial

from bench_runner import run_bench

GAME = "MinAtar/Breakout-v1"

run = partial(run_bench, "bench_baselines.py")  # the script as a user runs it


def row(report: str, method: str) -> list[str]:
    (line,) = [line for line in report.splitlines() if line.startswith(f"| `{GAME}` | {method} |")]
    return [cell.strip() for cell in line.strip("|").split("|")]


def test_a_tiny_run_is_reported_and_then_skipped(tmp_path):
    runs, out = tmp_path / "runs", tmp_path / "baselines.md"
    words = ["--games", "Breakout", "--methods", "A2C", "--seeds", "1", "--steps", "400",
             "--eval-episodes", "1", "--jobs", "1", "--run-dir", runs, "--out", out]
    done = run(*words, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    (evaluation,) = (runs / "MinAtar-Breakout-v1" / "A2C" / "seed1").glob("*/eval.json")
    result = json.loads(evaluation.read_text())
    assert result["episodes"] == 1 and result["global_step"] >= 400
    mean = result["mean_return"]
    assert f"{GAME} A2C seed 1: eval return {mean:.2f}" in done.stdout
    report = out.read_text()
    assert "Each run trains for 400 agent steps" in report and "on 1 full episodes" in report
    raw = json.loads(out.with_suffix(".json").read_text())
    (record,) = raw["records"]
    assert "--total-timesteps 400 --eval-episodes 1" in record["command"]
    random = raw["random"][GAME]
    assert random["episodes"] == 1 and random["std"] == 0.0  # one episode: no spread
    game, method, cell, seeds, random_cell, wall = row(report, "A2C")
    assert (game, method) == (f"`{GAME}`", "A2C")
    assert cell == seeds == f"{mean:.2f}"  # one seed: its return, no ±
    assert random_cell == f"{random['mean']:.2f} ± 0.00"
    assert wall == f"{record['seconds']:.0f} s"
    assert "Runs without a result" not in report

    # The same command again: the finished run is read back, not trained again.
    again = run(*words, cwd=tmp_path)
    assert again.returncode == 0, again.stderr[-2000:]
    assert list((runs / "MinAtar-Breakout-v1" / "A2C" / "seed1").iterdir()) == [evaluation.parent]
    (record,) = json.loads(out.with_suffix(".json").read_text())["records"]
    assert record["skipped"] is True and record["mean_return"] == mean
    assert row(out.read_text(), "A2C")[2:5] == [cell, seeds, random_cell]


def test_report_only_gives_mean_and_sample_std_over_the_seeds_done(tmp_path):
    runs, out = tmp_path / "runs", tmp_path / "baselines.md"
    game_dir = runs / "MinAtar-Breakout-v1"
    for method, seed, mean_return in [("A2C", 1, 1.0), ("A2C", 2, 2.0), ("A2C", 3, 4.0),
                                      ("OptionCritic", 2, 3.5)]:
        folder = game_dir / method / f"seed{seed}" / "run"
        folder.mkdir(parents=True)
        (folder / "eval.json").write_text(json.dumps({"mean_return": mean_return}))
    # A run killed before its evaluation: a checkpoint, no eval.json. Not resumed here.
    (game_dir / "A2C" / "seed4" / "run").mkdir(parents=True)
    (game_dir / "A2C" / "seed4" / "run" / "checkpoint.pt").write_bytes(b"")
    done = run("--games", "Breakout", "--methods", "A2C", "OptionCritic", "--seeds", 1, 2, 3, 4,
               "--eval-episodes", 1, "--report-only", "--run-dir", runs, "--out", out,
               cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    report = out.read_text()
    # 1, 2, 4: mean 7/3, sample variance ((4/3)² + (1/3)² + (5/3)²) / 2 = 7/3, std 1.5275.
    assert row(report, "A2C")[2:4] == ["2.33 ± 1.53 (3 of 4 seeds)", "1.00, 2.00, 4.00, –"]
    assert row(report, "OptionCritic")[2:4] == ["3.50 (1 of 4 seeds)", "–, 3.50, –, –"]
    assert row(report, "A2C")[5] == row(report, "OptionCritic")[5] == "–"  # no wall: not run here
    missing = [line for line in report.splitlines() if line.startswith("- MinAtar")]
    assert missing == [f"- {GAME} A2C seed 4: not run yet (the sweep was stopped before it)"] + [
        f"- {GAME} OptionCritic seed {s}: not run yet (the sweep was stopped before it)"
        for s in (1, 3, 4)]
    assert not (game_dir / "OptionCritic" / "seed1").exists()  # nothing was started
    assert sorted(p.name for p in (game_dir / "A2C" / "seed4" / "run").iterdir()) == [
        "checkpoint.pt"]


def test_bad_input_is_refused_in_one_line(tmp_path):
    for words, message in [
        (("--steps", "0"), "--steps must be at least 1, not 0"),
        (("--eval-episodes", "0"), "--eval-episodes must be at least 1, not 0"),
        (("--jobs", "0"), "--jobs must be at least 1, not 0"),
        (("--checkpoint-every", "-1"), "--checkpoint-every must be at least 0, not -1"),
        (("--seeds", "1", "2", "1"), "--seeds names a seed twice: 1 2 1"),
        (("--games", "Breakout", "Pong"), "--games Pong: no such MinAtar game (choose from "
                                          "Asterix, Breakout, Freeway, Seaquest, SpaceInvaders)"),
    ]:
        done = run(*words, "--run-dir", tmp_path / "runs", "--out", tmp_path / "out.md",
                   cwd=tmp_path)
        assert done.returncode == 2, (words, done.stderr)
        assert "Traceback" not in done.stderr
        assert done.stderr.strip().splitlines()[-1] == f"bench_baselines.py: error: {message}"
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # nothing run, nothing written
