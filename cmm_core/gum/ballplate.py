"""Uncertainty budget of the ball-plate calibration (thesis §3.8.2, eq. 3.14-3.29).

Model (thesis eq. 3.14), every term a correction with estimate 0 and an uncertainty::

    l_x = δl_vm + δl_is + δl_RP + δl_n - δl_Ax - l_0 [α δt_m + α δt_d + Δt_x δα]

The thesis prints the budget with placeholders ("x µm") for most values. The template fills
them from the thesis where it gives numbers and states every other value as an editable,
documented assumption (:class:`BallPlateBudgetInputs`):

- from the thesis: thermometer U(k=2) = 0.02 °C and 1.1 %RH (appendix 1); CMM uncertainty
  U(k=2) = sqrt(0.52² + (1.4e-3 l)²) µm (§6.2, appendix 1); alignment within 50 µm over the
  620 mm plate (§6.4; §3.8 says 10 µm, the larger is used); RH resolution 1 % (eq. 3.21);
  temperatures and humidities of the six measurements (the environment records above
  tables 6.1-6.6, :data:`THESIS_ENVIRONMENT`); CMM resolution 0.01 µm (the tables print
  1e-5 mm); plate pitch 133 mm, 5 x 5 balls (tables 6.1-6.6);
- assumed (not in the thesis): repeatability s = 0.5 µm from n = 5 repeats (the documented default
  repeatability), verification agreement 0.5 µm, probe reproducibility 0.2 µm, barometer
  U(k=2) = 20 Pa with 1 Pa resolution and p = 101 325 Pa (no pressure is recorded),
  thermometer resolution 0.01 °C, plate CTE 11.5e-6 /K with δα half-width 1e-6 /K
  (steel; ``sample_data/thesis/setup.json``), wavelength 632.99 nm.

Two readings of the thesis are made explicit:

- eq. 3.17 evaluates the "correction for the errors of indication of the CMM" δl_is from
  the resolution only. The CMM's own calibration uncertainty (appendix 1) is what that
  correction really carries; it is added as a separate, switchable contribution
  (``include_cmm_calibration``), and the resolution term is kept as eq. 3.17 has it.
- eq. 3.29 prints ``α/√3 · x`` (the same as eq. 3.28) while its text describes the
  uncertainty of the expansion coefficient times the temperature offset; the template uses
  ``u = l_0 · a(δα)/√3 · Δt`` with Δt the largest |t - 20 °C| of the record.

The air terms (eq. 3.19-3.25) use the modified Edlén equation (:mod:`cmm_core.gum.air`); the
sensitivity coefficients a_1..a_5 are ``l_0 ∂n/∂q``. For a CMM with glass scales the
refractive index does not enter the length (``include_air=False`` drops these terms); they
are negligible here anyway (about 0.01 µm at 752 mm).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..io import DataError, FileSource, read_json
from .air import refractive_index_sensitivities
from .evaluate import budget_from_dict
from .framework import GumResult, gum_combine
from .inputs import Contribution


@dataclass(frozen=True)
class EnvironmentRecord:
    """Temperature and humidity written above one of thesis tables 6.1-6.6."""

    position: str
    """Plate position (file name of the table), e.g. 'BP111'."""
    table: str
    """Thesis table, e.g. '6.1'."""
    t_start_C: float
    """Plate/air temperature at the start of the measurement, °C."""
    t_finish_C: float
    """Temperature at the finish, °C."""
    rh_start_percent: float
    """Relative humidity at the start, %."""
    rh_finish_percent: float
    """Relative humidity at the finish, %."""

    @property
    def t_mean_C(self) -> float:
        """Mean of start and finish temperature."""
        return 0.5 * (self.t_start_C + self.t_finish_C)

    @property
    def rh_mean_percent(self) -> float:
        """Mean of start and finish humidity."""
        return 0.5 * (self.rh_start_percent + self.rh_finish_percent)


THESIS_ENVIRONMENT: tuple[EnvironmentRecord, ...] = (
    EnvironmentRecord("BP111", "6.1", 20.0, 21.0, 52.0, 52.5),
    EnvironmentRecord("BP112", "6.2", 20.0, 20.5, 52.5, 52.0),
    EnvironmentRecord("BP211", "6.3", 21.0, 21.0, 51.0, 50.0),
    EnvironmentRecord("BP212", "6.4", 21.0, 20.8, 51.0, 50.0),
    EnvironmentRecord("BP311", "6.5", 21.0, 21.0, 50.0, 50.0),
    EnvironmentRecord("BP312", "6.6", 20.5, 20.6, 50.0, 50.0),
)
"""The environment records printed above thesis tables 6.1-6.6 (control (20 ± 1) °C,
(50 ± 10) %RH)."""


def average_environment() -> EnvironmentRecord:
    """Mean of the six records (20.58 → 20.82 °C, 51.08 → 50.75 %RH).

    The header of thesis table 6.7 prints 20.6 → 20.8 °C and 51.1 → 50.8 %RH, these values
    rounded (the table body itself is a copy of table 6.6).
    """
    recs = THESIS_ENVIRONMENT
    return EnvironmentRecord(
        "average", "6.7 header",
        float(np.mean([r.t_start_C for r in recs])), float(np.mean([r.t_finish_C for r in recs])),
        float(np.mean([r.rh_start_percent for r in recs])),
        float(np.mean([r.rh_finish_percent for r in recs])))


PLATE_PITCH_MM = 133.0
"""Nominal ball pitch of the thesis plate (tables 6.1-6.6)."""

PLATE_BALLS_PER_SIDE = 5
"""5 x 5 balls."""


def plate_lengths_mm(pitch_mm: float = PLATE_PITCH_MM, n: int = PLATE_BALLS_PER_SIDE
                     ) -> np.ndarray:
    """Distinct nominal ball-to-ball lengths of an n x n plate, ascending (133 ... 752.4 mm)."""
    if not pitch_mm > 0 or int(n) < 2:
        raise ValueError(f"expected pitch_mm > 0 and n >= 2, got {pitch_mm}, {n}.")
    v = {round(math.hypot(i, j), 12) for i, j in itertools.product(range(n), repeat=2)
         if (i, j) != (0, 0)}
    return np.array(sorted(v)) * pitch_mm


def cmm_uncertainty_um(length_mm: ArrayLike) -> np.ndarray:
    """CMM uncertainty U(k=2) = sqrt(0.52² + (1.4e-3 L)²) µm (thesis §6.2, appendix 1)."""
    L = np.asarray(length_mm, float)
    return np.sqrt(0.52**2 + (1.4e-3 * L) ** 2)


def plate_uncertainty_um(length_mm: ArrayLike) -> np.ndarray:
    """Ball-plate certificate uncertainty U(k=2) = sqrt(0.26² + (1.9e-3 L)²) µm (appendix 1)."""
    L = np.asarray(length_mm, float)
    return np.sqrt(0.26**2 + (1.9e-3 * L) ** 2)


@dataclass(frozen=True)
class BallPlateBudgetInputs:
    """Editable inputs of the ball-plate budget (thesis eq. 3.14-3.29); see module notes."""

    length_mm: float = 4 * math.sqrt(2) * PLATE_PITCH_MM
    """Nominal length l_0 (default: the longest diagonal, 752.4 mm)."""
    s_lx_um: float = 0.5
    """Observed (maximum) standard deviation s(l_x) of the repeated lengths (eq. 3.15)."""
    n_repeats: int = 5
    """Number n of repeated measurements; u = s/sqrt(n), dof n - 1 (eq. 3.15)."""
    verification_um: float = 0.5
    """Largest difference x between repeat verification measurements (eq. 3.16), rectangular
    half-width."""
    cmm_resolution_um: float = 0.01
    """CMM resolution x; half-width x/2 (eq. 3.17)."""
    include_cmm_calibration: bool = True
    """Add the CMM's calibration uncertainty sqrt(0.52² + (1.4e-3 L)²) µm (k=2, appendix 1)."""
    probe_reproducibility_um: float = 0.2
    """Probe-system reproducibility x, rectangular half-width (eq. 3.18)."""
    include_air: bool = True
    """Include the refractive-index terms (eq. 3.19-3.25)."""
    t_C: float = 20.7
    """Air/plate temperature, °C (operating point of the Edlén sensitivities)."""
    p_Pa: float = 101_325.0
    """Air pressure, Pa (not recorded in the thesis)."""
    rh_percent: float = 50.9
    """Relative humidity, %."""
    wavelength_nm: float = 632.99
    """Vacuum wavelength of the Edlén evaluation, nm."""
    rh_U_percent: float = 1.1
    """Hygrometer expanded uncertainty (k=2), %RH (appendix 1; eq. 3.20)."""
    rh_resolution_percent: float = 1.0
    """Hygrometer resolution, %RH (eq. 3.21 prints 1 %)."""
    p_U_Pa: float = 20.0
    """Barometer expanded uncertainty (k=2), Pa (eq. 3.22; assumed)."""
    p_resolution_Pa: float = 1.0
    """Barometer resolution, Pa (eq. 3.23; assumed)."""
    t_air_U_C: float = 0.02
    """Air thermometer expanded uncertainty (k=2), °C (appendix 1; eq. 3.24)."""
    t_resolution_C: float = 0.01
    """Thermometer resolution, °C (eq. 3.25; assumed)."""
    alignment_mm: float = 0.050
    """Misalignment of the plate over alignment_length_mm (§6.4: within 50 µm)."""
    alignment_length_mm: float = 620.0
    """Length over which the alignment is stated (the 620 mm plate)."""
    cte_per_K: float = 11.5e-6
    """Thermal expansion coefficient α of the plate (eq. 3.27-3.28)."""
    t_plate_U_C: float = 0.02
    """Plate thermometer expanded uncertainty (k=2), °C (appendix 1; eq. 3.27)."""
    t_distribution_C: float = 0.12
    """Half-width x of the plate temperature distribution during the measurement, °C
    (eq. 3.28; from a record: half the start-to-finish change, at least 0.05 °C)."""
    cte_half_width_per_K: float = 1.0e-6
    """Half-width of the correction δα of the expansion coefficient (eq. 3.29)."""
    dt_from_20_C: float = 0.82
    """Largest |t - 20 °C| during the measurement, multiplies δα (eq. 3.29)."""
    thermometer_correlation: float = 0.0
    """Correlation coefficient r between the calibration errors of the air thermometer
    (eq. 3.24) and the plate thermometer (eq. 3.27): both carry the U(k=2) = 0.02 °C of
    appendix 1; r = 1 when one thermometer (or one calibration certificate) serves both,
    0 (the thesis's reading, the default) when they were calibrated independently
    (JCGM 100 5.2.2, eq. 16). Used only with ``include_air``."""

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if f.type in ("bool",) or isinstance(v, bool):
                continue
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"{f.name}: expected a finite number, got {v!r}.")
            if f.name == "thermometer_correlation":
                if not -1.0 <= v <= 1.0:
                    raise ValueError(f"{f.name}: expected a correlation coefficient in "
                                     f"[-1, 1], got {v!r}.")
                continue
            if v < 0:
                raise ValueError(f"{f.name}: expected a value >= 0, got {v!r}.")
        if int(self.n_repeats) != self.n_repeats or self.n_repeats < 2:
            raise ValueError(f"n_repeats: expected an integer >= 2, got {self.n_repeats!r}.")
        if not self.alignment_mm < self.alignment_length_mm:
            raise ValueError(f"alignment_mm: expected less than alignment_length_mm "
                             f"({self.alignment_length_mm}), got {self.alignment_mm}.")

    @classmethod
    def from_dict(cls, d: dict) -> BallPlateBudgetInputs:
        """Inputs from a dict; unknown keys raise ValueError naming them."""
        names = {f.name for f in fields(cls)}
        bad = sorted(set(d) - names)
        if bad:
            raise ValueError(f"unknown budget input(s) {', '.join(bad)}; expected some of "
                             f"{', '.join(sorted(names))}.")
        return cls(**d)


def inputs_from_record(record: EnvironmentRecord, **overrides) -> BallPlateBudgetInputs:
    """Inputs for one measurement's environment record (thesis tables 6.1-6.6).

    t and RH are the record means; the plate temperature half-width is half the
    start-to-finish change (at least 0.05 °C, half the 0.1 °C step of the records); Δt for
    δα is the largest |t - 20 °C| of the record.
    """
    base: dict[str, Any] = {
        "t_C": record.t_mean_C,
        "rh_percent": record.rh_mean_percent,
        "t_distribution_C": max(0.5 * abs(record.t_finish_C - record.t_start_C), 0.05),
        "dt_from_20_C": max(abs(record.t_start_C - 20.0), abs(record.t_finish_C - 20.0)),
    }
    base.update(overrides)
    return replace(BallPlateBudgetInputs(), **base)


def default_inputs() -> BallPlateBudgetInputs:
    """Inputs for the average of the six thesis records (:func:`average_environment`)."""
    return inputs_from_record(average_environment())


@dataclass(frozen=True)
class BallPlateBudget:
    """The evaluated ball-plate budget at one length."""

    inputs: BallPlateBudgetInputs
    """Inputs used."""
    contributions: tuple[Contribution, ...]
    """Contributions (u in the input's unit, c in µm per unit), thesis equation in `unit`."""
    equations: tuple[str, ...]
    """Thesis equation of each contribution."""
    gum: GumResult
    """GUM result in µm (u_c, nu_eff, k, U, shares)."""
    correlations: tuple[tuple[str, str, float], ...] = ()
    """Correlated pairs ``(a, b, r)`` of contribution names (empty: independent inputs);
    pass them to :func:`~cmm_core.gum.mc.monte_carlo` with ``contributions``."""

    def table(self) -> list[dict]:
        """Budget rows with the thesis equation added."""
        rows = self.gum.table()
        for r, eq, ct in zip(rows, self.equations, self.contributions, strict=True):
            r["equation"] = eq
            r["unit"] = ct.unit
        return rows


_T_AIR_CAL = "δl_n air temperature, calibration (k=2)"
_T_PLATE_CAL = "α·δt_m plate thermometer (k=2)"


def _correlations(inp: BallPlateBudgetInputs) -> tuple[tuple[str, str, float], ...]:
    """The correlated pairs of the budget: the two thermometer calibrations (eq. 3.24, 3.27)."""
    if inp.include_air and inp.thermometer_correlation != 0.0:
        return ((_T_AIR_CAL, _T_PLATE_CAL, float(inp.thermometer_correlation)),)
    return ()


def _contributions(inp: BallPlateBudgetInputs) -> tuple[list[Contribution], list[str]]:
    L_um = inp.length_mm * 1e3
    out: list[tuple[str, Contribution]] = []

    def add(eq, ct):
        out.append((eq, ct))

    add("3.15", Contribution("l_x repeatability s/sqrt(n)", inp.s_lx_um / math.sqrt(inp.n_repeats),
                             "normal", c=1.0, dof=inp.n_repeats - 1, unit="µm"))
    add("3.16", Contribution.from_half_width("δl_vm verification measurement",
                                             inp.verification_um, c=1.0, unit="µm"))
    add("3.17", Contribution.from_half_width("δl_is CMM resolution", inp.cmm_resolution_um / 2,
                                             c=1.0, unit="µm"))
    if inp.include_cmm_calibration:
        add("app. 1", Contribution.from_half_width(
            "δl_is CMM error of indication (calibration, k=2)",
            float(cmm_uncertainty_um(inp.length_mm)), "normal", k=2.0, c=1.0, unit="µm"))
    add("3.18", Contribution.from_half_width("δl_RP probe reproducibility",
                                             inp.probe_reproducibility_um, c=1.0, unit="µm"))
    if inp.include_air:
        a = refractive_index_sensitivities(inp.t_C, inp.p_Pa, inp.rh_percent, inp.wavelength_nm)
        c_rh, c_p, c_t = (-L_um * a["dn_drh_per_percent"], -L_um * a["dn_dp_per_Pa"],
                          -L_um * a["dn_dt_per_K"])
        add("3.20", Contribution.from_half_width("δl_n humidity, calibration (k=2)",
                                                 inp.rh_U_percent, "normal", k=2.0, c=c_rh,
                                                 unit="%RH"))
        add("3.21", Contribution.from_half_width("δl_n humidity, resolution",
                                                 inp.rh_resolution_percent / 2, c=c_rh,
                                                 unit="%RH"))
        add("3.22", Contribution.from_half_width("δl_n pressure, calibration (k=2)",
                                                 inp.p_U_Pa, "normal", k=2.0, c=c_p, unit="Pa"))
        add("3.23", Contribution.from_half_width("δl_n pressure, resolution",
                                                 inp.p_resolution_Pa / 2, c=c_p, unit="Pa"))
        add("3.24", Contribution.from_half_width(_T_AIR_CAL,
                                                 inp.t_air_U_C, "normal", k=2.0, c=c_t, unit="°C"))
        add("3.25", Contribution.from_half_width("δl_n air temperature, resolution",
                                                 inp.t_resolution_C / 2, c=c_t, unit="°C"))
    theta = math.asin(inp.alignment_mm / inp.alignment_length_mm)
    add("3.26", Contribution.from_half_width("δl_Ax misalignment (cosine error)",
                                             L_um * (1.0 - math.cos(theta)), c=1.0, unit="µm"))
    c_alpha = -L_um * inp.cte_per_K
    add("3.27", Contribution.from_half_width(_T_PLATE_CAL, inp.t_plate_U_C,
                                             "normal", k=2.0, c=c_alpha, unit="°C"))
    add("3.28", Contribution.from_half_width("α·δt_d plate temperature distribution",
                                             inp.t_distribution_C, c=c_alpha, unit="°C"))
    add("3.29", Contribution.from_half_width("Δt·δα expansion coefficient",
                                             inp.cte_half_width_per_K,
                                             c=-L_um * inp.dt_from_20_C, unit="1/K"))
    return [c for _, c in out], [e for e, _ in out]


def ballplate_budget(inputs: BallPlateBudgetInputs | dict | None = None, *,
                     coverage_probability: float = 0.95) -> BallPlateBudget:
    """Evaluate the ball-plate calibration budget (thesis eq. 3.14-3.29) by JCGM 100.

    Parameters
    ----------
    inputs : BallPlateBudgetInputs or dict, optional
        Defaults to :func:`default_inputs` (average of the thesis records); a dict
        overrides fields of the defaults.
    coverage_probability : float
        p of the expanded uncertainty (k from the t distribution with nu_eff).

    Returns
    -------
    BallPlateBudget
        Contributions and the GUM result in µm.
    """
    if inputs is None:
        inputs = default_inputs()
    elif isinstance(inputs, dict):
        BallPlateBudgetInputs.from_dict(inputs)           # names checked
        inputs = replace(default_inputs(), **inputs)
    elif not isinstance(inputs, BallPlateBudgetInputs):
        raise ValueError(f"inputs: expected BallPlateBudgetInputs or dict, got "
                         f"{type(inputs).__name__}.")
    cts, eqs = _contributions(inputs)
    corr = _correlations(inputs)
    g = gum_combine(cts, coverage_probability=coverage_probability, correlations=corr)
    return BallPlateBudget(inputs=inputs, contributions=tuple(cts), equations=tuple(eqs), gum=g,
                           correlations=corr)


def thesis_budgets(length_mm: float | None = None) -> dict[str, BallPlateBudget]:
    """The budget for each thesis environment record (tables 6.1-6.6) and their average."""
    recs = (*THESIS_ENVIRONMENT, average_environment())
    kw = {} if length_mm is None else {"length_mm": float(length_mm)}
    return {r.position: ballplate_budget(inputs_from_record(r, **kw)) for r in recs}


@dataclass(frozen=True)
class LengthDependence:
    """U(L) of the ball-plate budget over the plate's lengths."""

    length_mm: np.ndarray
    """Nominal lengths L."""
    u_c_um: np.ndarray
    """Combined standard uncertainty at each L."""
    nu_eff: np.ndarray
    """Effective degrees of freedom at each L."""
    k: np.ndarray
    """Coverage factor at each L."""
    U_um: np.ndarray
    """Expanded uncertainty at each L."""
    fit_a_um: float
    """a of the least-squares fit U(L)² ≈ a² + (b L)² (the form of appendix 1)."""
    fit_b_per_mm: float
    """b (µm/mm) of that fit."""
    cmm_spec_U_um: np.ndarray = field(repr=False)
    """CMM specification sqrt(0.52² + (1.4e-3 L)²) µm at each L, for comparison."""
    plate_spec_U_um: np.ndarray = field(repr=False)
    """Plate certificate sqrt(0.26² + (1.9e-3 L)²) µm at each L, for comparison."""


def budget_vs_length(inputs: BallPlateBudgetInputs | dict | None = None,
                     lengths_mm: ArrayLike | None = None, *, coverage_probability: float = 0.95
                     ) -> LengthDependence:
    """U(L) over the ball-to-ball lengths (default :func:`plate_lengths_mm`, 133-752 mm)."""
    base = ballplate_budget(inputs, coverage_probability=coverage_probability).inputs
    L = plate_lengths_mm() if lengths_mm is None else np.asarray(lengths_mm, float).ravel()
    if L.size == 0 or not np.all(np.isfinite(L)) or np.any(L < 0):
        raise ValueError("lengths_mm: expected finite lengths >= 0.")
    res = [ballplate_budget(replace(base, length_mm=float(x)),
                            coverage_probability=coverage_probability).gum for x in L]
    U = np.array([r.U for r in res])
    A = np.column_stack([np.ones_like(L), L**2])
    coef, *_ = np.linalg.lstsq(A, U**2, rcond=None)
    a2, b2 = max(coef[0], 0.0), max(coef[1], 0.0)
    return LengthDependence(length_mm=L, u_c_um=np.array([r.u_c for r in res]),
                            nu_eff=np.array([r.nu_eff for r in res]),
                            k=np.array([r.k for r in res]), U_um=U,
                            fit_a_um=math.sqrt(a2), fit_b_per_mm=math.sqrt(b2),
                            cmm_spec_U_um=cmm_uncertainty_um(L),
                            plate_spec_U_um=plate_uncertainty_um(L))


def budget_spec_dict(budget: BallPlateBudget) -> dict:
    """The budget as the ``budget`` JSON of docs/formats.md (read by ``python -m cmm_core budget``)."""
    rows = []
    label = {ct.name: f"{ct.name} [eq. {eq}]"
             for ct, eq in zip(budget.contributions, budget.equations, strict=True)}
    for ct in budget.contributions:
        r = {"name": label[ct.name], "distribution": ct.distribution,
             "c": float(1.0 if ct.c is None else ct.c)}
        if ct.distribution == "normal":
            r["u"] = ct.u
        else:
            r["half_width"] = ct.half_width
        r["dof"] = None if math.isinf(ct.dof) else ct.dof
        r["unit"] = ct.unit
        rows.append(r)
    out = {"description": f"Ball-plate calibration budget, thesis eq. 3.14-3.29, "
                          f"L = {budget.inputs.length_mm:.1f} mm; result in µm.",
           "contributions": rows,
           "coverage_probability": budget.gum.coverage_probability,
           "monte_carlo_trials": 200000}
    if budget.correlations:
        out["correlations"] = [{"between": [label[a], label[b]], "r": r}
                               for a, b, r in budget.correlations]
    return out


def read_budget(source: FileSource, *, name: str | None = None,
                progress: Callable[[float, str], object] | None = None) -> dict:
    """Read and evaluate a budget JSON file (the ``budget`` command's input).

    The file is read like every JSON input (UTF-8 byte-order mark tolerated; binary or
    invalid JSON refused); every problem of its content is a :class:`~cmm_core.io.DataError`
    naming the budget file, the field and what was expected.

    Parameters
    ----------
    source : path, bytes or file-like
    name : str, optional
        File name for messages (default: the path's name).
    progress : callable, optional
        Passed to :func:`cmm_core.gum.budget_from_dict`.

    Returns
    -------
    dict
        The GUM (and, when trials are asked for, Monte Carlo) result.
    """

    d, name = read_json(source, name)
    try:
        return budget_from_dict(d, progress=progress)
    except (ValueError, TypeError, KeyError) as exc:
        raise DataError(str(exc).strip() or type(exc).__name__, file=name) from None
