"""`bench/probe_lr_cap.py` run as a user runs it, on a sweep folder made by hand: two games'
tune runs of A2C (whose scores are set so the verdicts are known before the probe trains),
each probed by one real run of 1,000 steps, and one of RAPL-A2C's whose probe diverges; a
second call resumes instead of training again; bad input is refused with a one-line error."""

from __future__ import annotations

import json
import re
from functools import partial
from pathlib import Path

from bench_runner import run_bench

run = partial(run_bench, "probe_lr_cap.py")  # the script as a user runs it

#: (game, learning rate, anneal, final score) of the hand-made tune runs. On Breakout every
#: grid point scores below any real return (−1), so the probe beats the grid there; on Asterix
#: the grid's best is 1,000, above any real return at 1,000 steps, so it cannot.
TUNE = [("Breakout", 7e-4, False, -1.0), ("Breakout", 1.4e-3, False, -2.0),
        ("Breakout", 1.4e-3, True, -1.5),
        ("Asterix", 7e-4, True, 1000.0), ("Asterix", 1.4e-3, False, 500.0)]
#: A tune run of RAPL-A2C's whose rate, doubled, drives the weights out of range within a
#: rollout or two: its probe diverges, an answer the report shows, not a fault.
DIVERGING = ("Breakout", 1e30, False, -1.0)


def make_sweep(root: Path) -> Path:
    sweep = root / "sweep"
    runs = []
    for i, (game, lr, anneal, score) in enumerate(TUNE + [DIVERGING]):
        method, mode = ("A2C", "a2c") if i < len(TUNE) else ("RAPL-A2C", "rapl")
        key = f"tune{i:08d}"
        env_id = f"MinAtar/{game}-v1"
        folder = sweep / "runs" / key
        folder.mkdir(parents=True)
        flags = {"env-id": env_id, "seed": 101, "total-timesteps": 1000, "eval-episodes": 1,
                 "seed-stride": 1000, "mode": mode, "num-envs": 4, "learning-rate": lr,
                 "anneal-lr": anneal}
        (folder / "config.json").write_text(json.dumps(
            {"key": key, "script": "rapl_a2c", "flags": flags, "needs": [], "steps": 1000}))
        (folder / "result.json").write_text(json.dumps({"eval": {"mean_return": score}}))
        runs.append({"env_id": env_id, "key": key, "method": method, "role": "main",
                     "script": "rapl_a2c", "seed": 1, "steps": 1000,
                     "variant": {"learning_rate": lr, "anneal_lr": anneal}})
    (sweep / "tune.json").write_text(json.dumps({"experiment": "tune", "runs": runs}))
    return sweep


def test_the_probe_doubles_the_top_rate_of_each_schedule_and_says_where_it_beats_the_grid(
        tmp_path):
    sweep = make_sweep(tmp_path)
    out = tmp_path / "probe"
    done = run(sweep, "--out", out, "--jobs", "2", cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "4 runs, 0 finished before, 4 to run" in done.stdout
    assert "RAPL-A2C MinAtar/Breakout-v1 seed 101: diverged" in done.stdout
    # Each probe is a tune run at A2C's top rate of its schedule (1.4e-3, constant and
    # annealed alike) with the rate doubled and its schedule kept: both games' constant runs
    # and Breakout's annealed one (Asterix's annealed run is at 7e-4, below the top).
    for i, anneal in ((1, False), (4, False), (2, True)):
        config = json.loads((out / "runs" / f"tune{i:08d}-x2" / "config.json").read_text())
        assert config["flags"]["learning-rate"] == 2.8e-3
        assert config["flags"]["anneal-lr"] is anneal and config["flags"]["num-envs"] == 4
        assert (out / "runs" / f"tune{i:08d}-x2" / "result.json").is_file()
    assert not (out / "runs" / "tune00000003-x2").exists()
    report = (out / "lr_cap_probe.md").read_text()
    rows = {r.split(" | ")[1]: r for r in report.splitlines() if r.startswith("| A2C |")}
    # The grid's best by hand: Breakout −1.00 at 7e-4 constant; Asterix 1000.00 at 7e-4
    # annealed; the top constant point's −2.00 and 500.00; the top annealed point's −1.50 on
    # Breakout and none on Asterix.
    assert rows["Breakout"].startswith(
        "| A2C | Breakout | -1.00 (0.0007 constant) | -2.00 | -1.50 | ")
    assert rows["Breakout"].endswith("(0.0028 annealed) | **yes** |")
    assert "(0.0028 constant) |" in rows["Breakout"]
    assert rows["Asterix"].startswith("| A2C | Asterix | 1000.00 (0.0007 annealed) | 500.00 | – | ")
    assert rows["Asterix"].endswith("(0.0028 constant) | – | no |")
    # RAPL-A2C's probe diverged: shown so, and it beats nothing (its grid's best is −1).
    (rapl,) = [r for r in report.splitlines() if r.startswith("| RAPL-A2C |")]
    assert rapl == ("| RAPL-A2C | Breakout | -1.00 (1e+30 constant) | -1.00 | – | "
                    "diverged (2e+30 constant) | – | no |")
    record = json.loads((out / "runs" / "tune00000005-x2" / "diverged.json").read_text())
    assert record["key"] == "tune00000005-x2"
    assert record["error"].startswith("rapl_a2c.py: error: training stopped")
    assert "A probe beats every grid point in 1 of 3 method-game cells." in report
    # Again: nothing trains (the diverged run neither), the same table.
    again = run(sweep, "--out", out, "--jobs", "2", cwd=tmp_path)
    assert again.returncode == 0 and "4 finished before, 0 to run" in again.stdout
    assert (out / "lr_cap_probe.md").read_text().split("\n", 3)[3] == report.split("\n", 3)[3]


def test_bad_input_is_refused_in_one_line(tmp_path):
    sweep = make_sweep(tmp_path)
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "tune.json").write_text("{\"runs\": [")
    for words, message in [
        ((broken, "--out", tmp_path / "o"), f"{broken / 'tune.json'}: not valid JSON"),
        ((tmp_path, "--out", tmp_path / "o"), f"{tmp_path} has no tune.json"),
        ((sweep, "--out", tmp_path / "o", "--jobs", "0"), "--jobs must be at least 1, not 0"),
    ]:
        done = run(*words)
        assert done.returncode == 2
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and re.match(r"probe_lr_cap\.py: error: ", lines[0])
        assert message in lines[0]
