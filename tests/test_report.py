"""The sweep report (`routine_gym.experiments.report`): a synthetic sweep folder with hand-chosen
scores and curves, and the tables, CSVs and figures worked out from them by hand."""

from __future__ import annotations

import csv
import hashlib
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.stats

from routine_gym.errors import UsageError
from routine_gym.experiments import (
    backends,
    drawing,
    reference,
    registry,
    report,
    statistics,
    training_curves,
)
from routine_gym.experiments.paper import ablation, diagnosis
from routine_gym.metrics import iqm

BREAKOUT = "MinAtar/Breakout-v1"  # demo-normalised: random 0, demo 10
ASTERIX = "MinAtar/Asterix-v1"  # demo-normalised: random 1, demo 21
ATARI = "ALE/Breakout-v5"  # human-normalised: random 1.7, human 30.5
RAW = "CartPole-v1"  # no demo, no table: raw
COINRUN = "procgen/CoinRun-v0"
DEMOS = {BREAKOUT: 10.0, ASTERIX: 21.0}
RANDOM = {BREAKOUT: 0.0, ASTERIX: 1.0}
REPS = 100
STEPS = 100

IMITATION = {"BC": (0.1, 0.2), "GAIL": (0.2, 0.3), "SQIL": (0.3, 0.4), "RAPL-SQIL": (0.5, 0.6)}
ABLATION = {"Full": 0.6, "RR": 0.3, "PbE": 0.35, "RF": 0.25, "ID": 0.5, "RP": 0.2,
            "BPE": 0.55}
# Hand-made training curves of A2C on Breakout: (step, episodic return).
CURVE_SEED_1 = [(3, 5.0), (4, 7.0), (9, 2.0), (100, 10.0)]
CURVE_SEED_2 = [(2, 4.0), (50, 8.0)]


class Sweep:
    """Writes a sweep folder as `routine-gym experiment run` leaves it."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.manifests: dict[str, list[dict]] = {}

    def run(self, experiment: str, method: str, env_id: str, seed: int, score: float | None,
            variant: dict | None = None, eval_extra: dict | None = None,
            evals: dict | None = None, curve: list | None = None,
            counters: dict | None = None) -> str:
        """One run; `score=None` leaves it unfinished (no result.json)."""
        variant = variant or {}
        blob = json.dumps([experiment, method, env_id, seed, variant], sort_keys=True)
        key = hashlib.sha256(blob.encode()).hexdigest()[:12]
        self.manifests.setdefault(experiment, []).append(
            {"key": key, "script": "rapl_a2c", "method": method, "env_id": env_id,
             "seed": seed, "variant": variant, "role": "main", "steps": STEPS})
        folder = self.out / "runs" / key
        folder.mkdir(parents=True)
        (folder / "config.json").write_text(json.dumps(
            {"key": key, "script": "rapl_a2c", "args": {}, "needs": [], "steps": STEPS}))
        run_dir = f"{env_id.replace('/', '-')}__rapl_a2c__{seed}__1796166756"
        if curve is not None:
            from torch.utils.tensorboard import SummaryWriter

            writer = SummaryWriter(str(folder / run_dir))
            for step, value in curve:
                writer.add_scalar("charts/episodic_return", value, step)
            writer.close()
        if score is not None:
            summary = {"env_id": env_id, "episodes": 2, "seed": seed + 10_000,
                       "returns": [score, score], "mean_return": score, "std_return": 0.0,
                       **(eval_extra or {})}
            (folder / "result.json").write_text(json.dumps(
                {"key": key, "run_dir": run_dir, "eval": summary, "evals": evals or {},
                 "seconds": 1.0, "finished": f"2026-12-0{seed}T10:00:00Z",
                 **({"counters": counters} if counters else {})}))
        return key

    def write(self, budget: str = "cpu") -> None:
        for experiment, runs in self.manifests.items():
            (self.out / f"{experiment}.json").write_text(json.dumps(
                {"experiment": experiment, "version": 1, "budget": budget,
                 "description": "test", "runs": runs}))


def _patch_references(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Known demo and random-policy scores; returns the envs the random policy was asked for."""
    played: list[str] = []

    def random_policy_scores(env_id, episodes, seed):
        played.append(env_id)
        return {"mean": RANDOM[env_id]}

    monkeypatch.setattr(reference, "demo_score",
                        lambda env_id, demo_set="current": DEMOS.get(env_id))
    monkeypatch.setattr(reference, "random_policy_scores", random_policy_scores)
    return played


#: The rl experiment's PPO runs by (method, game): each seed's score, None: not finished. Only
#: some finished: RAPL-PPO's seed 2 on Asterix is missing and MacroAction-PPO has no Asterix run.
PPO_SCORES = {("PPO", BREAKOUT): (4, 8), ("RAPL-PPO", BREAKOUT): (6, 9),
              ("MacroAction-PPO", BREAKOUT): (3, 5), ("PPO", ASTERIX): (10, 10),
              ("RAPL-PPO", ASTERIX): (12, None)}


def _ppo_runs(sweep: Sweep) -> None:
    for (method, env_id), scores in PPO_SCORES.items():
        for seed, score in enumerate(scores, start=1):
            sweep.run("rl", method, env_id, seed, score)


def _full_sweep(out: Path) -> tuple[Sweep, str]:
    sweep = Sweep(out)
    for method, (score, alignment) in IMITATION.items():
        for env_id in (ATARI, BREAKOUT, RAW):
            for seed in (1, 2):
                v = score + 0.02 * (seed - 1)  # the normalised score
                raw = {ATARI: 1.7 + 28.8 * v, BREAKOUT: 10 * v, RAW: 100 * v}[env_id]
                sweep.run("imitation", method, env_id, seed, raw,
                          eval_extra={"mean_alignment": alignment + 0.02 * (seed - 1)})
    for env_id, a2c, rapl in ((BREAKOUT, (4, 6), (6, 8)), (ASTERIX, (10, 10), (8, 9))):
        for seed in (1, 2):
            sweep.run("rl", "A2C", env_id, seed, a2c[seed - 1])
            sweep.run("rl", "RAPL-A2C", env_id, seed, rapl[seed - 1])
    missing = sweep.run("rl", "RAPL-A2C", BREAKOUT, 3, None)
    _ppo_runs(sweep)

    finals = {"A2C": (4, 6), "MacroAction": (5, 5), "OptionCritic": (3, 3), "CompILE": (1, 3),
              "RAPL-A2C": (9, 10)}
    for method, scores in finals.items():
        for seed in (1, 2):
            curve = ({1: CURVE_SEED_1, 2: CURVE_SEED_2}[seed] if method == "A2C"
                     else [(50, scores[seed - 1] - 1.0), (100, float(scores[seed - 1]))])
            sweep.run("curves", method, BREAKOUT, seed, scores[seed - 1], curve=curve)

    coinrun = {"A2C": ((8, 10), (6, 8), (2, 4)), "RAPL-A2C": ((10, 10), (8, 9), (3, 5))}
    for method, (train, easy, hard) in coinrun.items():
        for seed in (1, 2):
            i = seed - 1
            sweep.run("coinrun", method, COINRUN, seed, easy[i],
                      evals={"train": {"mean_return": train[i]}, "hard": {"mean_return": hard[i]}})

    s_a = {BREAKOUT: 5.0, ASTERIX: 10.0}
    for env_id in (BREAKOUT, ASTERIX):
        for seed in (1, 2):
            sweep.run("scalability", "A2C", env_id, seed, {BREAKOUT: (4, 6), ASTERIX: (10, 10)}[
                env_id][seed - 1])
            for k, length in ((1, 2), (3, 2), (6, 2), (3, 5)):
                for method in ("RAPL-A2C", "MacroAction"):
                    relative = ((0.2 if method == "RAPL-A2C" else -0.1) + 0.05 * (k - 3)
                                + 0.02 * (length - 2) + 0.2 * (seed - 1))
                    sweep.run("scalability", method, env_id, seed, s_a[env_id] * (1 + relative),
                              variant={"K": k, "min_length": length})

    for env_id in (BREAKOUT, ASTERIX):
        for seed in (1, 2):
            sweep.run("ablation", "A2C", env_id, seed,
                      {BREAKOUT: (4, 6), ASTERIX: (10, 10)}[env_id][seed - 1])
            for variant, value in ABLATION.items():
                v = value + 0.02 * (seed - 1)
                sweep.run("ablation", "RAPL-A2C", env_id, seed,
                          10 * v if env_id == BREAKOUT else 1 + 20 * v,
                          variant={"discovery": variant})
    # Diagnosis: A2C 4, 6 on Breakout; RAPL 2, 2 with half the updates; at A2C's updates 5, 5.
    diagnosis_runs = {("A2C", None): ((4, 6), 100, 1.0), ("RAPL-A2C", None): ((2, 2), 50, 2.0),
                      ("RAPL-A2C", "decisions"): ((5, 5), 100, 2.0),
                      ("RAPL-A2C", "authors"): ((2, 3), 50, 2.0),
                      ("MacroAction", "decisions"): ((1, 1), 100, 2.0)}
    for (method, kind), (scores, updates, per) in diagnosis_runs.items():
        for seed in (1, 2):
            bins = {"steps_per_decision": [per] * 4, "primitive_share": [1 / per] * 4}
            sweep.run("diagnosis", method, BREAKOUT, seed, scores[seed - 1],
                      variant={"diagnosis": kind} if kind else None,
                      counters={"decisions": updates * 80, "updates": updates,
                                "primitive_steps": int(updates * 80 * per),
                                "steps_per_decision": per, "primitive_share": 1 / per,
                                "episode_length": 20.0, "bins": bins})
    sweep.write()
    return sweep, missing


@pytest.fixture(scope="module")
def full(tmp_path_factory):
    """The full synthetic sweep and its report: (out, written paths, key of a missing run)."""
    out = tmp_path_factory.mktemp("sweep")
    _, missing = _full_sweep(out)
    with pytest.MonkeyPatch.context() as monkeypatch:
        _patch_references(monkeypatch)
        written = report.write_report(out, reps=REPS, seed=0)
    return out, written, missing


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_fig2_csv_has_the_relative_performance_per_game(full):
    out, _, _ = full
    rows = {r["env_id"]: r for r in _rows(out / "report" / "fig2_rl.csv")}
    # Breakout: A2C 4, 6 → S_A 5; RAPL 6, 8 → S_R 7: +40 %; s.e. of S_R = 1 → 1/5 = 20 %.
    assert float(rows[BREAKOUT]["S_A"]) == 5.0 and float(rows[BREAKOUT]["S_R"]) == 7.0
    assert float(rows[BREAKOUT]["relative_performance_pct"]) == pytest.approx(40.0)
    assert float(rows[BREAKOUT]["error_pct"]) == pytest.approx(20.0)
    # Asterix: A2C 10, 10; RAPL 8, 9 → 8.5: −15 %; s.e. 0.5 → 5 %.
    assert float(rows[ASTERIX]["relative_performance_pct"]) == pytest.approx(-15.0)
    assert float(rows[ASTERIX]["error_pct"]) == pytest.approx(5.0)
    # Sorted best first; the unfinished third seed is left out.
    assert [r["env_id"] for r in _rows(out / "report" / "fig2_rl.csv")] == [BREAKOUT, ASTERIX]
    assert rows[BREAKOUT]["runs_rapl"] == "2"


def test_report_md_counts_games_and_lists_missing_runs(full):
    out, _, missing = full
    text = (out / "report" / "report.md").read_text()
    assert "Budget: **cpu**" in text
    assert "Latest finished run: 2026-12-02T10:00:00Z" in text
    assert "same or better than A2C (S_R ≥ S_A) on 1 of 2 games" in text
    assert "paper: same or better on 25 of 33" in text
    assert f"17 of 19 runs finished; missing: `{missing}` (RAPL-A2C, {BREAKOUT}, seed 3), `" \
        in text and f"(RAPL-PPO, {ASTERIX}, seed 2)" in text
    # IQM of the normalised final scores of rl (see test_normalised_scores_and_iqm_by_hand).
    assert "| A2C | 45.0 % [" in text and "| RAPL-A2C | 50.0 % [" in text
    # The paper's Table 1 numbers sit beside ours.
    assert "| RAPL-SQIL | 0.610 ± 0.011 |" in text and "| 0.34 | 36.1 % |" in text
    assert "Normalisation" in text and "raw" in text


def test_fig2_ppo_csv_and_table_by_hand(full):
    out, _, _ = full
    rows = _rows(out / "report" / "fig2_rl_ppo.csv")
    assert [r["env_id"] for r in rows] == [BREAKOUT, ASTERIX]  # RAPL-PPO's +25 %, then +20 %
    breakout, asterix = rows
    # Breakout: PPO 4, 8 → S 6; RAPL-PPO 6, 9 → 7.5: +25 %, s.e. 1.5 (std 3/√2, over √2)
    # → 1.5/6 = 25 %; MacroAction-PPO 3, 5 → 4: −33.3 %, s.e. 1 → 16.7 %; RAPL-A2C over A2C
    # from Fig. 2: +40 % ± 20 %.
    assert (breakout["runs_ppo"], breakout["runs_rapl_ppo"], breakout["runs_macro_ppo"]) == (
        "2", "2", "2")
    assert [float(breakout[c]) for c in ("S_PPO", "S_RAPL_PPO", "S_MacroAction_PPO")] == [
        6.0, 7.5, 4.0]
    assert float(breakout["rapl_ppo_relative_pct"]) == pytest.approx(25.0)
    assert float(breakout["rapl_ppo_error_pct"]) == pytest.approx(25.0)
    assert float(breakout["macro_ppo_relative_pct"]) == pytest.approx(-100 / 3)
    assert float(breakout["macro_ppo_error_pct"]) == pytest.approx(100 / 6)
    assert float(breakout["rapl_a2c_relative_pct"]) == pytest.approx(40.0)
    assert float(breakout["rapl_a2c_error_pct"]) == pytest.approx(20.0)
    # Asterix: PPO 10, 10; RAPL-PPO one finished run, 12: +20 % ± 0 (one run); no
    # MacroAction-PPO: empty; RAPL-A2C 8, 9 over A2C 10, 10: −15 % ± 5 %.
    assert (asterix["runs_ppo"], asterix["runs_rapl_ppo"], asterix["runs_macro_ppo"]) == (
        "2", "1", "0")
    assert float(asterix["rapl_ppo_relative_pct"]) == pytest.approx(20.0)
    assert float(asterix["rapl_ppo_error_pct"]) == 0.0
    assert asterix["S_MacroAction_PPO"] == asterix["macro_ppo_relative_pct"] == ""
    assert float(asterix["rapl_a2c_relative_pct"]) == pytest.approx(-15.0)
    text = (out / "report" / "report.md").read_text()
    assert (f"| {BREAKOUT} | 2/2/2 | 6.00 | 7.50 | 4.00 | 25.0 % ± 25.0 % | -33.3 % ± 16.7 % | "
            "40.0 % ± 20.0 % |") in text
    assert (f"| {ASTERIX} | 2/1/0 | 10.00 | 12.00 | – | 20.0 % ± 0.0 % | – | "
            "-15.0 % ± 5.0 % |") in text
    assert "RAPL-PPO same or better than PPO (S ≥ S_PPO) on 2 of 2 games" in text
    # The PPO aggregate: Breakout alone (MacroAction-PPO has no Asterix run), demo-normalised
    # (random 0, demo 10): PPO {0.4, 0.8} → IQM 0.6, RAPL-PPO {0.6, 0.9} → 0.75, MacroAction-PPO
    # {0.3, 0.5} → 0.4. P(RAPL-PPO > PPO): 6 beats 4, 9 beats 4 and 8, 6 loses to 8: 3/4;
    # P(MacroAction-PPO > PPO): only 5 > 4 of the four pairs: 1/4.
    ppo = text[text.index("**PPO, beyond the paper**"):text.index("## Fig. 3")]
    assert f"Left out of the aggregates: {ASTERIX}" in ppo
    for line in ("| PPO | 60.0 % [", "| RAPL-PPO | 75.0 % [", "| MacroAction-PPO | 40.0 % [",
                 "| RAPL-PPO > PPO | 0.75 [", "| RAPL-PPO > MacroAction-PPO | 1.00 [1.00, 1.00] |",
                 "| MacroAction-PPO > PPO | 0.25 ["):
        assert line in ppo, line
    assert ppo.count("Probability of improvement") == 1  # one table of the three pairs


def test_the_ppo_part_leaves_fig2_as_it_was_and_needs_no_ppo_run(tmp_path, monkeypatch):
    """The same A2C runs with the PPO runs, without them (a sweep from before) and with only
    PPO's finished: Fig. 2's CSV, PNG and table are the same bytes wherever A2C ran."""
    _patch_references(monkeypatch)
    folders = {}
    for case in ("with", "without", "ppo only"):
        sweep = Sweep(tmp_path / case)
        for env_id, a2c, rapl in ((BREAKOUT, (4, 6), (6, 8)), (ASTERIX, (10, 10), (8, 9))):
            for seed in (1, 2):
                if case != "ppo only":
                    sweep.run("rl", "A2C", env_id, seed, a2c[seed - 1])
                    sweep.run("rl", "RAPL-A2C", env_id, seed, rapl[seed - 1])
        if case != "without":
            _ppo_runs(sweep)
        sweep.write()
        report.write_report(sweep.out, reps=REPS)
        folders[case] = sweep.out / "report"
    with_ppo, without = folders["with"], folders["without"]
    for name in ("fig2_rl.csv", "fig2_rl.png"):
        assert (with_ppo / name).read_bytes() == (without / name).read_bytes(), name
    assert not list(without.glob("fig2_rl_ppo.*"))
    a2c_part = (without / "report.md").read_text()
    a2c_part = a2c_part[a2c_part.index("Figure: `fig2_rl.png`"):a2c_part.index("## Fig. 3")]
    text = (with_ppo / "report.md").read_text()
    assert text[text.index("Figure: `fig2_rl.png`"):text.index("**PPO, beyond")] == a2c_part
    assert "8 of 8 runs finished" in (without / "report.md").read_text()
    # Only PPO's runs: an empty Fig. 2, the PPO part as in the full sweep.
    only = folders["ppo only"]
    assert (only / "fig2_rl_ppo.csv").read_text() == (with_ppo / "fig2_rl_ppo.csv").read_text(
        ).replace("40.0,20.0", ",").replace("-15.0,5.0", ",")
    assert _rows(only / "fig2_rl.csv") == []
    assert "RAPL-PPO same or better than PPO (S ≥ S_PPO) on 2 of 2 games" in (
        only / "report.md").read_text()


def test_bin_curve_means_episodes_per_bin_and_carries_forward():
    x, y = training_curves.bin_curve([s for s, _ in CURVE_SEED_1], [v for _, v in CURVE_SEED_1],
                            total_steps=100)
    assert x[:5].tolist() == [2.0, 4.0, 6.0, 8.0, 10.0] and x[-1] == 100.0 and len(x) == 50
    # (0, 2] has no episode yet; (2, 4] holds 5 and 7; (8, 10] holds 2; then carried to 100.
    assert math.isnan(y[0])
    assert y[1:4].tolist() == [6.0, 6.0, 6.0]
    assert y[4:49].tolist() == [2.0] * 45
    assert y[49] == 10.0


def test_fig3_csv_has_mean_and_std_of_the_binned_curves(full):
    out, _, _ = full
    rows = {float(r["step"]): r for r in _rows(out / "report" / "fig3_curves.csv")
            if r["method"] == "A2C"}
    assert len(rows) == training_curves.CURVE_BINS
    # Step 2: only seed 2 has an episode (4). Step 4: seeds 6 and 4. Step 100: 10 and 8.
    assert (float(rows[2.0]["mean_return"]), rows[2.0]["runs"]) == (4.0, "1")
    assert float(rows[2.0]["std_return"]) == 0.0
    assert float(rows[4.0]["mean_return"]) == 5.0
    assert float(rows[4.0]["std_return"]) == pytest.approx(math.sqrt(2))
    assert float(rows[50.0]["mean_return"]) == 5.0  # seed 1 carries 2, seed 2 has 8
    assert float(rows[100.0]["mean_return"]) == 9.0 and rows[100.0]["runs"] == "2"


def test_curve_bins_sums_and_counts_each_bin_by_hand():
    sums, counts = training_curves.curve_bins([3, 4, 9, 12], [5.0, 7.0, 2.0, 1.0],
                                              total_steps=10, bins=5)
    # (2, 4] holds 5 and 7; (8, 10] holds 2 and the episode past the budget (1).
    assert sums.tolist() == [0.0, 12.0, 0.0, 0.0, 3.0]
    assert counts.tolist() == [0, 2, 0, 0, 2]
    assert training_curves.curve_values(sums, counts)[1:].tolist() == [6.0, 6.0, 6.0, 1.5]


def test_fig3_from_the_curves_kept_in_result_json_without_tensorboard_logs(full, tmp_path):
    """A committed snapshot keeps no TensorBoard log: the binned curve of `result.json` draws
    the same Fig. 3."""
    import shutil

    out, _, _ = full
    copy = tmp_path / "snapshot"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("report"))
    logs = list(copy.glob("runs/*/*/events.out.tfevents.*"))
    assert logs
    for log in logs:
        result_path = log.parent.parent / "result.json"
        result = json.loads(result_path.read_text())
        # what the sweep keeps
        result["curve"], _ = backends.curve_and_counters(log.parent, {"steps": STEPS,
                                                                        "flags": {}})
        result_path.write_text(json.dumps(result))
        shutil.rmtree(log.parent)
    with pytest.MonkeyPatch.context() as monkeypatch:
        _patch_references(monkeypatch)
        report.write_report(copy, reps=REPS, seed=0)
    assert _rows(copy / "report" / "fig3_curves.csv") == _rows(
        out / "report" / "fig3_curves.csv")


def test_read_episodic_returns_drops_what_a_resumed_run_relogged(tmp_path):
    from torch.utils.tensorboard import SummaryWriter

    for points in ([(10, 1.0), (20, 2.0), (30, 3.0)], [(20, 5.0), (40, 6.0)]):
        writer = SummaryWriter(str(tmp_path))
        for step, value in points:
            writer.add_scalar("charts/episodic_return", value, step)
        writer.close()
    steps, returns = training_curves.read_episodic_returns(tmp_path)
    assert steps.tolist() == [10, 20, 40] and returns.tolist() == [1.0, 5.0, 6.0]


def test_normalised_scores_and_iqm_by_hand(full):
    out, _, _ = full
    refs = json.loads((out / "report" / "reference_scores.json").read_text())["envs"]
    assert refs[BREAKOUT] == {"normalisation": "demo", "random": 0.0, "reference": 10.0,
                              "score_key": None, "note": ""}
    assert refs[ATARI]["normalisation"] == "human"
    assert (refs[ATARI]["random"], refs[ATARI]["reference"]) == (1.7, 30.5)
    assert refs[RAW]["normalisation"] == "raw"
    assert reference.Reference("demo", 1.0, 21.0).normalise(11.0) == 0.5
    assert reference.Reference("human", 1.7, 30.5, ATARI).normalise(30.5) == pytest.approx(1.0)

    # Imitation: the normalised scores b and b + 0.02 on both normalised games (CartPole is
    # raw, out of the aggregate); IQM of {b, b, b + .02, b + .02} = b + 0.01.
    rows = {r["method"]: r for r in _rows(out / "report" / "table1_imitation.csv")}
    for method, (score, alignment) in IMITATION.items():
        assert float(rows[method]["score_iqm"]) == pytest.approx(score + 0.01)
        assert float(rows[method]["score_ci_lo"]) <= float(rows[method]["score_iqm"])
        assert float(rows[method]["score_iqm"]) <= float(rows[method]["score_ci_hi"])
        # Alignment over all 6 runs: a three times, a + 0.02 three times.
        assert float(rows[method]["alignment_mean"]) == pytest.approx(alignment + 0.01)
        assert float(rows[method]["alignment_std"]) == pytest.approx(0.01 * math.sqrt(6 / 5))
    # RL: A2C normalised {0.4, 0.6, 0.45, 0.45} → IQM of the middle two 0.45; RAPL-A2C
    # {0.6, 0.8, 0.35, 0.4} → (0.4 + 0.6)/2 = 0.5.
    assert iqm([0.4, 0.6, 0.45, 0.45]) == pytest.approx(0.45)


def test_iqm_point_is_the_trimmed_mean_inside_a_reproducible_ci():
    scores = np.random.default_rng(3).normal(size=(5, 4))
    first = statistics.iqm_intervals({"m": scores}, reps=REPS, seed=7)["m"]
    point, lo, hi = first
    assert point == pytest.approx(scipy.stats.trim_mean(scores, 0.25, axis=None))
    assert point == pytest.approx(iqm(scores))
    assert lo <= point <= hi and lo < hi
    # The same seed gives the same interval, whatever else drew from NumPy's global RNG.
    np.random.default_rng().random()
    assert statistics.iqm_intervals({"other": scores + 1, "m": scores}, reps=REPS, seed=7)["m"] \
        == first


def test_probability_of_improvement_of_a_dominating_method_is_one(full):
    scores = np.random.default_rng(0).normal(size=(3, 4))
    assert statistics.probability_of_improvement(scores + 10, scores, reps=REPS) == (1.0, 1.0, 1.0)
    assert statistics.probability_of_improvement(scores, scores, reps=REPS)[0] == 0.5
    out, _, _ = full
    text = (out / "report" / "report.md").read_text()
    for other in ("BC", "GAIL", "SQIL"):
        assert f"| RAPL-SQIL > {other} | 1.00 [1.00, 1.00] |" in text
    for other in ("A2C", "MacroAction", "OptionCritic", "CompILE"):
        assert f"| RAPL-A2C > {other} | 1.00 [1.00, 1.00] |" in text


def test_every_figure_is_a_valid_png_with_its_csv(full):
    import matplotlib.image

    out, written, _ = full
    folder = out / "report"
    stems = [s for e in registry.EXPERIMENTS.values() if (out / f"{e.name}.json").exists()
             for s in e.files]
    for stem in stems:
        if stem == diagnosis.COMPARISONS_FILE:  # a table: its CSV alone
            assert folder / f"{stem}.csv" in written
            continue
        png = folder / f"{stem}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert png.stat().st_size > 10_000
        image = matplotlib.image.imread(png)
        assert image.shape[0] > 300 and image.shape[1] > 500
        assert png in written and folder / f"{stem}.csv" in written
    assert written[-1] == folder / "report.md"
    assert not list(folder.glob(".*.tmp"))


def test_diagnosis_csvs_give_the_verdict_and_each_runs_counters(full):
    out, _, _ = full
    (row,) = _rows(out / "report" / "diagnosis.csv")
    # A2C 5 ± 1 (2 seeds); RAPL 2, 2; at A2C's updates 5. Welch's t with ν = 1:
    # p = 1 − (2/π)·atan|t|; RAPL: t = −3/1, p = 0.205; the decisions budget: Δ 0, p = 1.
    assert float(row["A2C mean"]) == 5.0 and float(row["A2C se"]) == 1.0
    assert float(row["RAPL-A2C, decisions budget mean"]) == 5.0
    assert row["verdict"].startswith(
        "RAPL-A2C vs A2C: no evidence (Δ -3.00, p = 0.205); RAPL-A2C, decisions budget vs "
        "A2C: no evidence (Δ +0.00, p = 1.000)")
    runs = _rows(out / "report" / "diagnosis_runs.csv")
    assert len(runs) == 10
    rapl = [r for r in runs if r["variant"] == "RAPL-A2C"]
    assert {(r["updates"], r["decisions"], r["steps_per_decision"]) for r in rapl} == {
        ("50", "4000", "2.0")}
    assert {r["routine_share"] for r in rapl} == {"0.5"}
    text = (out / "report" / "report.md").read_text()
    assert "## Diagnosis " in text and "| MinAtar/Breakout-v1 | RAPL-A2C | 2 | 50 | 4000 |" in text


def test_coinrun_csv_has_mean_and_std_over_seeds_per_level_set(full):
    out, _, _ = full
    rows = {(r["method"], r["levels"]): r for r in _rows(out / "report" / "fig4_coinrun.csv")}
    assert float(rows["A2C", "train"]["mean_return"]) == 9.0
    assert float(rows["A2C", "train"]["std_return"]) == pytest.approx(math.sqrt(2))
    assert float(rows["A2C", "easy"]["mean_return"]) == 7.0
    assert float(rows["RAPL-A2C", "hard"]["mean_return"]) == 4.0


def test_scalability_csv_is_relative_to_a2c_with_se_over_seeds(full):
    out, _, _ = full
    rows = _rows(out / "report" / "fig5_scalability.csv")
    # RAPL-A2C at K 3, length 2: +20 % on both games with seed 1, +40 % with seed 2.
    chosen = [r for r in rows if (r["method"], r["K"], r["min_length"]) == ("RAPL-A2C", "3", "2")]
    assert {r["panel"] for r in chosen} == {"K", "min_length"}
    for row in chosen:
        assert float(row["relative_mean_pct"]) == pytest.approx(30.0)
        assert float(row["relative_se_pct"]) == pytest.approx(10.0)
        assert (row["games"], row["seeds"]) == ("2", "2")
    macro = next(r for r in rows if (r["method"], r["K"], r["min_length"])
                 == ("MacroAction", "3", "5"))
    assert float(macro["relative_mean_pct"]) == pytest.approx(6.0)
    assert [r["K"] for r in rows if r["panel"] == "K" and r["method"] == "MacroAction"] \
        == ["1", "3", "6"]


def test_ablation_csv_has_the_iqm_of_each_variant(full):
    out, _, _ = full
    rows = {r["variant"]: r for r in _rows(out / "report" / "fig6_ablation.csv")}
    assert list(rows) == [*ablation.VARIANTS, "A2C"]
    for variant, value in ABLATION.items():
        assert float(rows[variant]["score_iqm"]) == pytest.approx(value + 0.01)
    assert float(rows["A2C"]["score_iqm"]) == pytest.approx(0.45)


def test_experiments_not_run_are_named_and_only_their_files_are_missing(tmp_path, monkeypatch):
    played = _patch_references(monkeypatch)
    sweep = Sweep(tmp_path)
    for seed, (a, r) in enumerate(((4, 6), (6, 8)), start=1):
        sweep.run("rl", "A2C", BREAKOUT, seed, a)
        sweep.run("rl", "RAPL-A2C", BREAKOUT, seed, r)
    sweep.run("curves", "A2C", BREAKOUT, 1, None)
    sweep.write(budget="smoke")
    written = report.write_report(tmp_path, reps=REPS)
    names = sorted(p.name for p in written)
    assert names == ["fig2_rl.csv", "fig2_rl.png", "reference_scores.json", "report.md"]
    text = (tmp_path / "report" / "report.md").read_text()
    assert "not run (no `imitation.json` in the sweep folder)" in text
    assert "0 of 1 runs finished" in text and "No finished run: no figure." in text
    assert played == [BREAKOUT]

    # The random policy's score is cached: a second report does not play again.
    def refuse(*args):
        raise AssertionError("played the random policy again")

    monkeypatch.setattr(reference, "random_policy_scores", refuse)
    report.write_report(tmp_path, reps=REPS)


def test_absent_or_empty_sweep_folder_is_a_one_line_usage_error(tmp_path):
    with pytest.raises(UsageError, match=r"nowhere: no such sweep folder") as absent:
        report.write_report(tmp_path / "nowhere")
    assert "\n" not in str(absent.value)
    with pytest.raises(UsageError, match=rf"{tmp_path}: not a sweep folder"):
        report.write_report(tmp_path)


def test_importing_the_report_loads_no_heavy_library():
    code = ("import sys, routine_gym.experiments.report\n"
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'torch', 'ale_py', "
            "'procgen', 'rliable', 'matplotlib', 'tensorboard'}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]"


def test_performance_profiles_count_the_runs_above_each_threshold():
    # 4 scores: 0.1, 0.3, 0.5, 0.9 → above 0: all; above 0.4: 0.5 and 0.9; above 1: none.
    scores = {"A": np.array([[0.1, 0.5], [0.3, 0.9]])}
    profiles = statistics.performance_profiles(scores, np.array([0.0, 0.4, 1.0]), reps=50)
    profile, lo, hi = profiles["A"]
    assert profile.tolist() == [1.0, 0.5, 0.0]
    assert np.all(lo <= profile + 1e-12) and np.all(profile <= hi + 1e-12)


def test_each_method_and_ablation_variant_has_its_own_colour():
    # Fig. 6 is read beside Figs. 2-5: a variant drawn in a baseline's colour reads as that
    # baseline. Only Full is RAPL-A2C itself and shares its colour.
    variants = {v: c for v, c in ablation.VARIANT_COLOURS.items() if v != "Full"}
    assert set(ablation.VARIANT_COLOURS) == set(ablation.VARIANTS)
    assert ablation.VARIANT_COLOURS["Full"] == drawing.COLOURS["RAPL-A2C"]
    colours = list(drawing.COLOURS.values()) + list(variants.values())
    assert len({c.lower() for c in colours}) == len(colours)


def test_each_arm_of_the_diagnosis_figure_has_its_own_colour():
    # The diagnosis figure draws A2C, RAPL-A2C and every variant side by side (bars and the
    # counters' lines): two arms in one colour cannot be told apart.
    arms = {"A2C": drawing.COLOURS["A2C"], "RAPL-A2C": drawing.COLOURS["RAPL-A2C"],
            **diagnosis.VARIANT_COLOURS}
    assert len({c.lower() for c in arms.values()}) == len(arms), arms
