"""The samples the effect search sees on a long recording: a bounded budget, spread in time.

Which effects are present is decided on the screening block (search/state.py) by fits and
held-out scores; their cost grows with the record's length, not only with the rows the fits
use, since the play operators and the drive low-passes run over every command. A few tens
of thousands of samples per actuator decide the search, so a record longer than the budget
is cut, for the search only, into one contiguous window per training / held-out block of
the alignment (align.py: even blocks train, odd blocks are held out), centred in its block:
the windows cover the whole run, so slow effects (drift, the temperature's course) still see
its full time span, and every window is scored held-out or trained on as its block is. At a
high sample rate, where such windows would be shorter than their lead-in (below), fewer
pairs of adjacent blocks are taken, spread evenly from the run's start to its end.

Each window keeps ``COMMAND_SETTLING_S`` of commands before its first sample, the margin
gaps.py gives after a command hole: the longest delay searched and the play operator's
state are settled by then. A drive low-pass slower than that sees the window's lead-in,
not the whole history (as after a command hole). The final fit of the grid (tiles.py)
draws its samples from the whole record, never from these windows.

``SEARCH_BUDGET`` counts sample-actuator values (samples per actuator times the block's
actuators), like search/state.py's fit and score budgets. The identification sweep's recordings
(testing/standgen/sweep.py: at most 36 s at 500 Hz on 8 x 8, 1.15 M; 24 s at 5 kHz on 4
actuators, 0.48 M) and the demo's test stand (43.2 s at 250 Hz on the 8 x 8 block, 0.69 M)
stay whole; 5 minutes at 500 Hz on the 8 x 8 block (9.6 M) is searched on 16 windows of
3.9 s (62.5 s), 1 minute at 5 kHz (19.2 M) on 6 windows of 1.04 s.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Final

import numpy as np

from es_calibration.data.align import AlignedData
from es_calibration.data.gaps import COMMAND_SETTLING_S
from es_common.arrays import IndexArray

#: Sample-actuator values the effect search sees at most (see the module docstring).
SEARCH_BUDGET: Final = 2_000_000


class SearchBudgetError(ValueError):
    """A search budget that is not a positive number of sample-actuator values."""


def search_windows(aligned: AlignedData, budget: int) -> list[tuple[int, int]]:
    """Return the (start, stop) sample rows of the search's windows, or [] when all fit.

    One window per block of ``aligned.block_edges``, centred in it, together at most
    ``budget // actuators`` samples. When that would make the windows shorter than their
    ``COMMAND_SETTLING_S`` lead-in (a high sample rate), fewer of them: pairs of adjacent
    blocks (one trained on, one held out; at least two pairs) spread evenly from the run's
    first pair to its last, so that the lead-ins cost at most as many commands as the
    windows. A window is never longer than its block.

    Raises:
        SearchBudgetError: ``budget`` is not positive.

    """
    if budget <= 0:
        raise SearchBudgetError(f"search budget must be positive, got {budget}")
    per_actuator = budget // max(aligned.n_actuators, 1)
    if aligned.t.size <= per_actuator:
        return []
    edges = aligned.block_edges
    blocks = edges.size - 1
    pairs = max(int(per_actuator / aligned.sample_rate / (2.0 * COMMAND_SETTLING_S)), 2)
    chosen = np.arange(blocks)
    if pairs < blocks // 2:
        first = np.unique(np.round(np.linspace(0, blocks // 2 - 1, pairs)).astype(np.intp))
        chosen = np.sort(np.concatenate([2 * first, 2 * first + 1]))
    rows = max(per_actuator // chosen.size, 1)
    half = 0.5 * min(rows / aligned.sample_rate, float(np.min(np.diff(edges))))
    centres = 0.5 * (edges[chosen] + edges[chosen + 1])
    starts = np.searchsorted(aligned.t, centres - half)
    stops = np.minimum(np.searchsorted(aligned.t, centres + half), starts + rows)
    return [(int(a), int(b)) for a, b in zip(starts, stops, strict=True) if b > a]


def search_span(aligned: AlignedData, budget: int = SEARCH_BUDGET) -> AlignedData:
    """Return the part of ``aligned`` the effect search sees (``aligned`` itself when it fits).

    ``aligned`` is the screening block's alignment; the result holds the samples of
    :func:`search_windows` and the commands from ``COMMAND_SETTLING_S`` before each window
    to its end, with the block's whole-run command period and mean temperature (the model's
    reference), its temperature series, drops and gaps.

    Raises:
        SearchBudgetError: ``budget`` is not positive.

    """
    windows = search_windows(aligned, budget)
    if not windows:
        return aligned
    rows: IndexArray = np.concatenate([np.arange(a, b) for a, b in windows]).astype(np.intp)
    t = aligned.t
    times = aligned.command_times
    keep = np.zeros(times.size, dtype=bool)
    for a, b in windows:
        # the command in effect at the lead-in's start, to one past the last sample's
        lo = max(int(np.searchsorted(times, t[a] - COMMAND_SETTLING_S, side="right")) - 1, 0)
        hi = int(np.searchsorted(times, t[b - 1], side="right")) + 1
        keep[lo:hi] = True
    index = aligned.sample_index
    return replace(
        aligned,
        t=t[rows],
        displacement=aligned.displacement[rows],
        valid=aligned.valid[rows],
        train=aligned.train[rows],
        sample_index=index[rows] if index.size == t.size else index,
        command_times=times[keep],
        command=aligned.command[keep],
        command_finite=aligned.command_finite[keep],
        dropped=dict(aligned.dropped),
        grid_mean_temperature=aligned.mean_temperature,
        command_period_s=aligned.command_period,
    )
