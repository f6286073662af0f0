"""Adding an experiment is one definition (one file in `routine_gym/experiments/paper/`) and one
`register` line: a toy experiment defined here is listed, planned, built and reported like the
paper's six, with nothing else changed."""

from __future__ import annotations

import csv
import json

import pytest

from routine_gym.cli import main
from routine_gym.experiments import registry, report, sweep
from routine_gym.experiments.drawing import colour, figure
from routine_gym.experiments.experiment import Experiment
from routine_gym.experiments.results import RunRecord
from routine_gym.experiments.specs import Builder
from routine_gym.experiments.writing import Writer, table

BREAKOUT = "MinAtar/Breakout-v1"

# -- the toy experiment: what its file in routine_gym/experiments/paper/ would hold ------------

FILE = "figt_toy"


def add_runs(b: Builder) -> None:
    """A2C on each game and seed of the budget."""
    for env_id in b.budget.games:
        for seed in b.seeds():
            b.a2c("A2C", env_id, seed)


def section(w: Writer, runs: list[RunRecord]) -> list[str]:
    """Each finished run's score, as a CSV, a bar chart and a table."""
    done = sorted((r for r in runs if r.finished), key=lambda r: (r.env_id, r.seed))
    rows = [(r.env_id, r.seed, r.score) for r in done]
    w.csv(FILE, ("env_id", "seed", "score"), rows)
    fig = figure(4, 3)
    fig.subplots().bar(range(len(rows)), [s for _, _, s in rows], color=colour("A2C"))
    w.png(fig, FILE)
    return ["Toy: each run's final score.", "", *table(("env", "seed", "score"), rows)]


TOY = Experiment(name="toy", version=1, title="Toy: A2C's final scores", figure="Fig. T",
                 file=FILE, add_runs=add_runs, section=section, normalised=False,
                 methods=("A2C",))


# -- the test --------------------------------------------------------------------------------


@pytest.fixture
def toy_registered():
    registry.register(TOY)  # the one registration line
    try:
        yield TOY
    finally:
        del registry.EXPERIMENTS["toy"]
        registry.games.cache_clear()


def test_registering_a_second_experiment_of_a_name_is_refused(toy_registered):
    with pytest.raises(ValueError, match="'toy' is registered already"):
        registry.register(TOY)


def test_a_toy_experiment_is_listed_planned_built_and_reported(toy_registered, tmp_path, capsys):
    assert main(["experiment", "list"]) == 0
    listed = capsys.readouterr().out
    assert "toy          Fig. T" in listed and "Toy: A2C's final scores" in listed

    assert sweep.plan("toy", "smoke") == [("toy", None)]
    entries = registry.build("toy", "smoke")
    assert [(e.method, e.env_id, e.seed) for e in entries] == [("A2C", BREAKOUT, 1)]
    assert registry.count_runs("toy", "smoke") == (1, 1_000)

    # A tiny sweep folder as `experiment run toy --budget smoke` leaves it.
    (tmp_path / "toy.json").write_text(json.dumps({
        "experiment": "toy", "version": 1, "budget": "smoke", "description": "smoke",
        "runs": [e.manifest() for e in entries]}))
    run = tmp_path / "runs" / entries[0].run.key
    run.mkdir(parents=True)
    (run / "result.json").write_text(json.dumps({
        "key": entries[0].run.key, "eval": {"mean_return": 4.5}, "finished": "2026-12-02"}))

    written = report.write_report(tmp_path, reps=10)

    folder = tmp_path / "report"
    assert {p.name for p in written} == {"figt_toy.csv", "figt_toy.png", "report.md",
                                         "reference_scores.json"}
    with open(folder / "figt_toy.csv", newline="") as fh:
        assert list(csv.reader(fh)) == [["env_id", "seed", "score"], [BREAKOUT, "1", "4.5"]]
    text = (folder / "report.md").read_text()
    assert "## Fig. T — Toy: A2C's final scores (`toy`)" in text
    assert "1 of 1 runs finished." in text
    assert f"| {BREAKOUT} | 1 | 4.5 |" in text
    assert "## Fig. 2 — RL: relative performance of RAPL-A2C over A2C per game (`rl`)" in text
    assert "not run (no `rl.json` in the sweep folder)." in text


def test_a_removed_experiment_s_files_are_removed_by_the_next_report(toy_registered, tmp_path):
    entries = registry.build("toy", "smoke")
    (tmp_path / "toy.json").write_text(json.dumps({
        "budget": "smoke", "runs": [e.manifest() for e in entries]}))
    run = tmp_path / "runs" / entries[0].run.key
    run.mkdir(parents=True)
    (run / "result.json").write_text(json.dumps({"eval": {"mean_return": 1.0}}))
    report.write_report(tmp_path, reps=10)
    assert (tmp_path / "report" / "figt_toy.png").exists()

    (run / "result.json").unlink()  # no finished run: no figure, and the old one goes
    report.write_report(tmp_path, reps=10)
    assert not (tmp_path / "report" / "figt_toy.png").exists()
    assert not (tmp_path / "report" / "figt_toy.csv").exists()
