"""`bench/bench_interrupt.py` run as a user runs it, with a tiny budget and this checkout as the
`--before` side: its report has one row per configuration (before, off, on) whose SPS is the one
its run printed, ratios worked out from those SPS, only `on` run with `--interrupt`, and the
vector env's step timed for before and off; bad input is refused with a one-line error before
any run starts."""

from __future__ import annotations

import re
from functools import partial
from pathlib import Path

from bench_runner import run_bench

ROOT = Path(__file__).resolve().parent.parent

run = partial(run_bench, "bench_interrupt.py")  # the script as a user runs it


def test_one_round_writes_a_row_per_configuration_and_the_ratios(tmp_path):
    out = tmp_path / "interrupt.md"
    done = run("--before", ROOT, "--steps", 80, "--repeats", 1, "--margin", 0.5,
               "--env-step-rounds", 1, "--out", out, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    printed = {name: int(sps) for name, sps in
               re.findall(r"^round 1 +(before|off|on): SPS +(\d+)", done.stdout, re.M)}
    assert list(printed) == ["before", "off", "on"]
    report = out.read_text()
    assert (f"`python bench/bench_interrupt.py --before {ROOT} --steps 80 --env-id "
            f"MinAtar/Breakout-v1 --margin 0.5 --repeats 1 --env-step-rounds 1 --out {out}`"
            ) in report
    commands = dict(re.findall(r"^- `(before|off|on)`: `python (.*)`$", report, re.M))
    assert commands["before"] == commands["off"]  # both sides are this checkout
    assert commands["on"] == commands["off"] + " --interrupt 0.5"
    assert "--total-timesteps 80 " in commands["off"] and "--mode rapl" in commands["off"]
    rows = {}
    for line in report.splitlines():
        if re.match(r"\| (before|off|on) \|", line):
            cells = [cell.strip() for cell in line.strip("|").split("|")]
            rows[cells[0]] = cells
    assert list(rows) == ["before", "off", "on"]
    for name, cells in rows.items():
        # One run: its SPS is the best; its routine use a percentage, its return a number.
        assert cells[1] == cells[2] == str(printed[name])
        assert float(cells[3]) > 0 and re.fullmatch(r"[\d.]+%", cells[4])
        float(cells[5])
    sps = printed
    assert (f"off / before: {sps['off'] / sps['before']:.3f} (best runs), "
            f"{sps['off'] / sps['before']:.3f} (means), {sps['off'] / sps['before']:.3f} "
            f"(medians); on / off: {sps['on'] / sps['off']:.3f} (best), "
            f"{sps['on'] / sps['off']:.3f} (means).") in report
    assert "best of 5 blocks of 4,000, 1 interleaved rounds:" in report
    steps = dict(re.findall(r"^- `(before|off)`: ([\d.]+) \(best \2\)$", report, re.M))
    assert list(steps) == ["before", "off"] and all(float(us) > 0 for us in steps.values())


def test_bad_input_is_refused_in_one_line(tmp_path):
    for words, message in [
        (("--before", ROOT, "--steps", "0"), "--steps must be at least 1, not 0"),
        (("--before", ROOT, "--repeats", "0"), "--repeats must be at least 1, not 0"),
        (("--before", ROOT, "--env-step-rounds", "-1"),
         "--env-step-rounds must be at least 0, not -1"),
        (("--before", ROOT, "--margin", "-0.5"), "--margin must be at least 0 (nats), not -0.5"),
        (("--before", tmp_path), f"--before {tmp_path} is not a routine-gym checkout (it has no "
                                 "algos/rapl_a2c.py)"),
        (("--before", ROOT, "--env-id", "MinAtar/Pong-v1"),
         f"--env-id MinAtar/Pong-v1 has no demo {ROOT}/demos/MinAtar-Pong-v1.npz"),
        ((), "the following arguments are required: --before"),
    ]:
        done = run(*words, "--out", tmp_path / "out.md", cwd=tmp_path)
        assert done.returncode == 2, (words, done.stderr[-2000:])
        assert "Traceback" not in done.stderr
        assert done.stderr.strip().splitlines()[-1] == f"bench_interrupt.py: error: {message}"
    assert not (tmp_path / "out.md").exists()
