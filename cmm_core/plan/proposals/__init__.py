"""Measure next: the extra measurement that settles what the data cannot (issue 29).

When the diagnosis cannot tell two effects A and B apart (aliases, runners-up), this package
generates candidate measurements from the data set's own setup and machine range, and
scores each by what it decides: the discrimination between A and B the augmented data set
(current data plus the candidate) would give, per minute of machine time.

One module per step, each importing only those above it:

- :mod:`.candidates`: the candidate measurements (:class:`NextMeasurement`: the plate
  moved, turned or stood up, new styli, repeats, instruments; each of a family,
  :data:`FAMILIES`) and the plate's grid read from its certificate (:func:`plate_grid`).
- :mod:`.append`: a candidate measured on the virtual CMM: appended to the data set
  (:func:`append_measurement`, :func:`repeat_from_fit`), its own observations
  (:func:`measurement_observations`), an instrument on the data's machine
  (:func:`instrument_of`); whether the machine reaches it (:func:`out_of_reach`,
  :func:`instrument_out_of_reach`: every probed ball of every stylus, every instrument
  point, inside the strokes without slack); the data set as a fit selects it
  (:func:`restrict`).
- :mod:`.rivals`: the sets of rivals a diagnosis leaves open (pairs, whole alias sets) (:func:`open_pairs`,
  :func:`rivals_of`) and each rival fitted to the current data (:func:`fit_rivals`, the
  placement scales' :class:`ScaleFit`).
- :mod:`.separation`: how well a candidate separates two rivals: the power of the nested
  F-test on the augmented design and its expectation over the rival's fitted size (how a
  candidate is scored).
- :mod:`.ranking`: the candidates scored and ranked (:func:`propose`, :func:`propose_many`
  on Dask; :class:`Proposal`, :class:`Proposals`, the unreachable ones as
  :class:`Skipped`), and the conclusion (:func:`conclusion`: the best next measurement,
  or that none decides and which wider family might).
- :mod:`.outcomes`: what a chosen proposal leads to: the diagnosis of its simulated data
  with each rival the truth (:func:`simulate_outcomes`, :func:`truth_config`) and its
  ``plan`` file (:func:`plan_file`).
"""

from __future__ import annotations

from .append import (
    append_measurement,
    instrument_of,
    instrument_out_of_reach,
    measurement_observations,
    out_of_reach,
    reached_range,
    repeat_from_fit,
    restrict,
)
from .candidates import (
    FAMILIES,
    REPEAT_BALLS,
    SHIFT_FRACTION,
    STYLUS_OFFSET_MM,
    WIDER,
    NextMeasurement,
    PlateGrid,
    blocked_styli,
    instrument_candidates,
    last_placement,
    measurement_candidates,
    plate_grid,
    repeat_candidates,
    styli_at,
    wide_candidates,
)
from .outcomes import Outcome, plan_file, simulate_outcomes, truth_config
from .ranking import (
    CHUNK,
    DECIDE_POWER,
    NO_POWER,
    TARGET_POWER,
    Proposal,
    Proposals,
    Skipped,
    conclusion,
    decide_bar,
    propose,
    propose_many,
)
from .rivals import (
    BASELINE,
    PLACEMENT_SCALE,
    PSEUDO,
    SCALE_RTOL,
    RivalFits,
    ScaleFit,
    check_rivals,
    fit_rivals,
    function_of,
    open_pairs,
    rival_pairs,
    rivals_of,
    scale_columns,
)

__all__ = [
    # candidates
    "NextMeasurement", "PlateGrid", "plate_grid", "measurement_candidates", "blocked_styli",
    "repeat_candidates", "wide_candidates", "instrument_candidates", "SHIFT_FRACTION",
    "STYLUS_OFFSET_MM", "REPEAT_BALLS", "FAMILIES", "WIDER", "styli_at", "last_placement",
    # append
    "append_measurement", "repeat_from_fit", "restrict", "measurement_observations",
    "instrument_of", "out_of_reach", "instrument_out_of_reach", "reached_range",
    # rivals
    "BASELINE", "PSEUDO", "PLACEMENT_SCALE", "SCALE_RTOL", "rival_pairs", "open_pairs",
    "rivals_of", "RivalFits", "fit_rivals", "ScaleFit", "scale_columns", "check_rivals",
    "function_of",
    # ranking
    "TARGET_POWER", "NO_POWER", "CHUNK", "Proposal", "Proposals", "propose", "propose_many",
    "DECIDE_POWER", "decide_bar", "Skipped", "conclusion",
    # outcomes
    "truth_config", "Outcome", "simulate_outcomes", "plan_file",
]
