"""`Experiment`: everything about one experiment in one object, so that an experiment is one
file (`routine_gym/experiments/paper/`) and one line in `registry.py`.

The object says which runs the experiment has at a budget (`add_runs`), how the report shows
them (`section`, which writes its figure `{file}.png` and the CSV behind it and returns its part
of `report.md`), what its labels are called and coloured (`methods`, `colours`), and whether the
report normalises its scores (`normalised`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from routine_gym.experiments.results import RunRecord
from routine_gym.experiments.specs import Builder
from routine_gym.experiments.writing import Writer

__all__ = ["Experiment"]


@dataclass(frozen=True)
class Experiment:
    """One experiment: its runs, its report section and its labels."""

    #: What `routine-gym experiment run NAME` and the manifest `OUT/{name}.json` call it.
    name: str
    #: Bumped when its runs change, so a sweep folder of the old runs is refused.
    version: int
    #: One line: what it measures (`experiment list`, the heading in `report.md`).
    title: str
    #: Where the paper shows it: "Table 1", "Fig. 2", ...
    figure: str
    #: The stem of its figure and CSV in `OUT/report/` (`table1_imitation`).
    file: str
    #: Adds its runs at the builder's budget (`Builder.run`, `Builder.a2c`).
    add_runs: Callable[[Builder], None]
    #: Writes its figure and CSV through the writer and returns its lines of `report.md`,
    #: from the main runs of its manifest (at least one finished).
    section: Callable[[Writer, list[RunRecord]], list[str]]
    #: Whether its games' reference scores are needed (its aggregates normalise scores).
    normalised: bool = True
    #: Its methods (or variants) in the order of its tables and figures.
    methods: tuple[str, ...] = ()
    #: Colours of its own labels that are not methods (`drawing.COLOURS` has the methods').
    colours: Mapping[str, str] = field(default_factory=dict)
    #: Stems of further files its section writes (the curves' performance profiles).
    extra_files: tuple[str, ...] = ()
    #: Whether its runs are points of a tuning grid: a run that diverges is its point's answer
    #: (the point loses the choice), not a failure of the sweep.
    grid: bool = False

    @property
    def files(self) -> tuple[str, ...]:
        """Every file stem its section may write into `OUT/report/`."""
        return (self.file, *self.extra_files)
