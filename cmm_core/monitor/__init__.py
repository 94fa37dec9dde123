"""Between calibrations: interim checks of a machine against its stored calibration, and
its calibration history (issue 28, ``docs/monitoring.md``).

Owns: :mod:`.check` (:func:`interim_check`: the χ² test of new measurements against a
stored model, poses fitted as nuisances, E_n per observation at k = 2), :mod:`.changes`
(:func:`what_changed`: the stored model refitted on the new data as its own prior),
:mod:`.explain` (:func:`explain_change`: the fewest physical changes that explain the
new data, by nested tests), :mod:`.blunder` (:func:`find_blunders`: a misprobe named
before the machine is blamed),
:mod:`.unseen` (:func:`unseen_words`: what a check cannot see, in words),
:mod:`.identity` (which machine a model is of, which version made it),
:mod:`.conformity` (the ISO 14253-1 statement against the MPE), :mod:`.history`
(:func:`compare_calibrations`: a machine's calibrations compared), :mod:`.outcome`
(:func:`run_check`: the check, what changed, the new effect named by the diagnosis, the
verdict and conformity), :mod:`.numbers` (:func:`json_num`: JSON-safe numbers of
both results sections), :mod:`.scenario`
(:func:`remeasured`: a simulated machine measured again). May import: ``machine``,
``io``, ``model``, ``diagnosis``, ``gum``, ``export``.
"""

from __future__ import annotations

from .blunder import MAX_BLUNDERS, Blunder, find_blunders, worst_observation
from .changes import MIN_RESOLVED, Changes, holm, projected, what_changed
from .check import (
    MAX_OBSERVATIONS,
    PROBE_TOLERANCE_MM,
    CheckSystem,
    GlsFit,
    InterimCheck,
    check_sigma_um,
    check_system,
    en_definition,
    gls_fit,
    interim_check,
)
from .conformity import (
    MPE_MAX_A_UM,
    MPE_MIN_D,
    RULE,
    STATEMENTS,
    Conformity,
    conformity,
    parse_mpe,
)
from .explain import (
    ALIAS_CHI2,
    STYLUS_U_MAX_UM,
    ChangeExplanation,
    ChangeSystem,
    Hypothesis,
    Step,
    change_system,
    difference_covariance,
    explain_change,
    explain_difference,
    hypotheses,
    select_changes,
    shares_certificate,
)
from .history import (
    CALIBRATION_CHI2_ALPHA,
    HISTORY_RULE,
    INFLATION_RULE,
    MAX_MAP_NODES_PER_AXIS,
    STYLUS_TOLERANCE_UM,
    History,
    compare_calibrations,
)
from .identity import machine_of, refuse_mixed_machines, refuse_other_machine, version_notes
from .numbers import json_num
from .outcome import (
    CHANGE_RULE,
    TARGETED_SHARE,
    TEST_RULE,
    VERDICTS,
    CheckOutcome,
    NewEffects,
    name_new_effects,
    run_check,
    scale_temperatures,
)
from .scenario import remeasured
from .unseen import (
    CARRIER_WEIGHT,
    MAX_CARRIERS,
    combination_text,
    distinct_words,
    unseen_example,
    unseen_words,
)

__all__ = ["CheckSystem", "check_sigma_um", "check_system", "GlsFit", "gls_fit", "interim_check", "InterimCheck",
           "MAX_OBSERVATIONS", "PROBE_TOLERANCE_MM", "remeasured", "Changes", "MIN_RESOLVED", "what_changed",
           "Conformity", "conformity", "parse_mpe", "RULE", "STATEMENTS", "holm", "History",
           "compare_calibrations", "MAX_MAP_NODES_PER_AXIS", "CheckOutcome", "NewEffects",
           "name_new_effects", "run_check", "VERDICTS", "TARGETED_SHARE", "TEST_RULE", "CHANGE_RULE",
           "HISTORY_RULE", "json_num", "machine_of", "refuse_mixed_machines",
           "refuse_other_machine", "version_notes", "MPE_MAX_A_UM", "MPE_MIN_D",
           "en_definition", "unseen_words", "combination_text", "unseen_example",
           "distinct_words", "CARRIER_WEIGHT", "MAX_CARRIERS", "ALIAS_CHI2",
           "ChangeExplanation", "Hypothesis", "Step", "explain_change", "hypotheses",
           "MAX_BLUNDERS", "Blunder", "find_blunders", "worst_observation",
           "explain_difference", "select_changes", "ChangeSystem", "change_system",
           "projected", "STYLUS_U_MAX_UM", "STYLUS_TOLERANCE_UM",
           "difference_covariance", "shares_certificate", "CALIBRATION_CHI2_ALPHA", "INFLATION_RULE",
           "scale_temperatures"]
