"""The result of a fit: estimates, uncertainties, residuals and the χ² test of the model
(thesis §4.5.1; the χ² test and Birge ratio as in CODATA's practice for inconsistent
data)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats

from ..machine import KinematicTerms
from ..units import p_text
from .problem import Problem
from .state import State

CHI2_ALPHA = 0.01
"""Level of the χ² (model adequacy) test behind ``FitResult.fails_chi2_test``."""

__all__ = ["FitResult", "CHI2_ALPHA"]


@dataclass(frozen=True)
class FitResult:
    """Outcome of a kinematic-model fit.

    Attributes
    ----------
    status : str
        ``converged``, ``max_iterations`` or ``failed``.
    message : str
        Plain-language summary, including what the data cannot determine.
    iterations : int
        Gauss-Newton iterations taken.
    spec : str
        Canonical model spec.
    plate : str
        Plate geometry mode: fixed, prior or free; none in an instrument-only fit.
    sigma_um : float
        Stated measurement repeatability used for weights and χ².
    labels, units, groups : list of str
        Name, unit and block of each parameter.
    values : ndarray
        Parameter estimates (plate: deviation from certificate or starting plate in µm;
        placement: deviation from the setup's nominal placement).
    u : ndarray
        Standard uncertainties (NaN for parameters the data cannot determine).
    covariance : ndarray
        Parameter covariance by the law of propagation of uncertainty: the probing noise
        (σ) and, with the certificate fixed, the certificate's own uncertainty.
    residuals_um : ndarray (n, 3)
        Corrected measurement minus placed ball, per observation.
    table : DataFrame
        The observations used (position, probe, ball, source file and row).
    rms_um : float
        RMS of all residual components of the plate observations (NaN in an
        instrument-only fit: ``instruments.summary`` gives each instrument's).
    chi2, dof, chi2_dof : float
        χ² against ``sigma_um`` (plus prior terms), degrees of freedom, and their ratio.
    bic : float
        Bayesian information criterion χ² + rank · ln(number of residuals).
    rank : int
        Numerical rank of the constrained problem (effective number of parameters).
    rank_rtol : float
        Relative singular-value tolerance used for the rank.
    unidentifiable : list of str
        Parameters carrying weight in a combination the data cannot determine.
    null_combinations : list of str
        Those combinations, written out with their loadings (for experts: "1.00·dzy[2] +
        0.79·syz").
    null_words : list of str
        The same combinations in words, one sentence each (:func:`.words.null_words`:
        "The z offsets of styli 1 and 2 and the z positions of placements B1 and B2
        cannot be told apart.").
    n_obs : int
        Observations (probed ball centres) used.
    problem : Problem
        The problem (layout, observations, kinematic terms) for prediction.
    state : State
        Final plate coordinates, placements and parameter vector.
    design_null : ndarray (k, n_params)
        Rows ``N`` of the constraints ``N x = 0`` that hold the combinations this design
        cannot determine (decided at the nominal linearisation); an augmented model scored
        from this fit keeps them (``diagnosis.scoring.score``).
    chi2_test, dof_test : float, int
        The statistic behind the χ² test and the Birge ratio: ``chi2`` and ``dof``, except
        with the certificate fixed, where the certificate's uncertainty is counted (the χ²
        of the same model with the certificate as a prior): its calibration errors are
        not the model's misfit. None means equal to ``chi2``, ``dof``.
    covariance_noise : ndarray or None
        The part of ``covariance`` due to the probing noise alone, when the certificate's
        own uncertainty is propagated into it (certificate fixed, ``certificate_prior``);
        None: ``covariance`` is all noise.
    certificate_sensitivity : ndarray or None
        With the certificate fixed: each parameter's change per standard uncertainty of
        each certificate coordinate (parameters × 3 per ball of ``problem.obs.balls``):
        ``covariance - covariance_noise`` is ``S Sᵀ``; None otherwise.
    """

    status: str
    message: str
    iterations: int
    spec: str
    plate: str
    sigma_um: float
    labels: list
    units: list
    groups: list
    values: np.ndarray
    u: np.ndarray
    covariance: np.ndarray
    residuals_um: np.ndarray
    table: pd.DataFrame
    rms_um: float
    chi2: float
    dof: int
    chi2_dof: float
    bic: float
    rank: int
    rank_rtol: float
    unidentifiable: list
    null_combinations: list
    n_obs: int
    problem: Problem = field(repr=False)
    state: State = field(repr=False)
    design_null: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), repr=False)
    chi2_test: float | None = None
    dof_test: int | None = None
    covariance_noise: np.ndarray | None = field(default=None, repr=False)
    certificate_sensitivity: np.ndarray | None = field(default=None, repr=False)
    null_words: list = field(default_factory=list)

    @property
    def terms(self) -> KinematicTerms:
        """Kinematic terms of the model."""
        return self.problem.terms

    @property
    def certificate_u_source(self) -> str:
        """Where the certificate's uncertainty, used by every χ² test and propagated
        uncertainty of this fit, came from (the file, the setup's statement, exact)."""
        return self.problem.obs.cert_u_source

    def block(self, name: str) -> tuple[list, np.ndarray, np.ndarray]:
        """``(labels, values, u)`` of one parameter block (labels: a list of str)."""
        s = self.problem.layout.blocks.get(name, slice(0, 0))
        return self.labels[s], self.values[s], self.u[s]

    @property
    def kinematic_coef(self) -> np.ndarray:
        """Kinematic coefficients (µm, µrad)."""
        return self.values[self.problem.layout.blocks["kinematic"]]

    @property
    def kinematic_cov(self) -> np.ndarray:
        """Covariance of the kinematic coefficients."""
        s = self.problem.layout.blocks["kinematic"]
        return self.covariance[s, s]

    @property
    def chi2_test_dof(self) -> float:
        """χ²/dof of the statistic behind the χ² test (``chi2_test / dof_test``): equal to
        ``chi2_dof`` unless the certificate is fixed, where its uncertainty is counted."""
        chi2, dof = self.test_statistic
        return chi2 / max(dof, 1)

    @property
    def birge_ratio(self) -> float:
        """sqrt(χ²/dof) of the statistic behind the χ² test: how much larger the scatter
        is than the stated repeatability (and, with the certificate fixed, than the
        certificate's uncertainty) allows. It scales the noise part of the uncertainties
        (``u_inflated``); the certificate's part, counted in the statistic, is not
        scaled."""
        return float(np.sqrt(self.chi2_test_dof))

    @property
    def test_statistic(self) -> tuple:
        """``(χ², dof)`` behind the χ² test (see ``chi2_test``)."""
        if self.chi2_test is None:
            return self.chi2, self.dof
        return self.chi2_test, self.dof_test

    @property
    def test_counts_certificate(self) -> bool:
        """True when the tested statistic is not the fit's own χ² (the certificate's
        uncertainty counted), so that both are worth quoting."""
        chi2, dof = self.test_statistic
        return not (abs(chi2 / max(dof, 1) - self.chi2_dof) < 5e-3 * max(self.chi2_dof, 1e-9)
                    and dof == self.dof)

    @property
    def chi2_p_value(self) -> float:
        """P-value of the χ² test of the model against the stated repeatability:
        the probability of a χ² at least this large at ``dof`` degrees of freedom when the
        model is right and σ is true (upper tail)."""
        chi2, dof = self.test_statistic
        return float(stats.chi2.sf(chi2, max(dof, 1)))

    @property
    def fails_chi2_test(self) -> bool:
        """True when χ² is too large for noise at the 1 % level (:data:`CHI2_ALPHA`): the
        model misses something or σ is understated, and σ-based uncertainties are too small.
        A fixed threshold on χ²/dof would be too strict for small fits and too lenient for
        large ones (χ²/dof = 1.31 at 543 dof is 5 standard deviations above 1)."""
        return self.chi2_p_value < CHI2_ALPHA

    @property
    def u_inflated(self) -> np.ndarray:
        """Uncertainties with their noise part scaled by the Birge ratio when it exceeds
        1: the honest figure when the model does not explain the data to the stated
        noise. The certificate's propagated part (certificate fixed) stays as it is."""
        b2 = max(1.0, self.birge_ratio) ** 2
        if self.covariance_noise is None:
            return self.u * np.sqrt(b2)
        noise = np.clip(np.diag(self.covariance_noise), 0, None)
        cert = np.clip(np.diag(self.covariance) - noise, 0, None)
        return np.where(np.isnan(self.u), np.nan, np.sqrt(b2 * noise + cert))

    @property
    def identifiable(self) -> bool:
        """True when the data determine every parameter."""
        return not self.unidentifiable

    def summary(self) -> dict:
        """The fit's headline numbers, the one place the CLI, the report and the app take
        them from: model, status and message, observations and determined parameters,
        RMS (µm), χ²/dof with its dof, the χ² test (p, verdict, Birge ratio, the tested
        χ²/dof and dof when the certificate is counted), BIC, plate mode, layout and where
        the certificate's uncertainty came from."""
        return {"model": self.spec, "status": self.status, "message": self.message,
                "n_obs": self.n_obs, "n_params": self.rank, "rms_um": self.rms_um,
                "chi2_dof": self.chi2_dof, "dof": self.dof, "chi2_p_value": self.chi2_p_value,
                "fails_chi2_test": self.fails_chi2_test, "birge_ratio": self.birge_ratio,
                "bic": self.bic, "plate": self.plate, "layout": self.terms.layout,
                "certificate_u_source": self.certificate_u_source,
                "chi2_test_dof": self.chi2_test_dof, "dof_test": self.dof_test}

    def history_row(self, change: str) -> dict:
        """One row of a diagnosis history (the app's, the report's, the analysis
        record's): ``spec``, ``change``, ``rms_um``, ``chi2_dof``, ``bic``, ``n_params``,
        rounded as shown."""
        return {"spec": self.spec, "change": change, "rms_um": round(self.rms_um, 4),
                "chi2_dof": round(self.chi2_dof, 3), "bic": round(self.bic, 1),
                "n_params": self.rank}

    def parameters_frame(self) -> pd.DataFrame:
        """Parameter table: name, block, unit, value, standard uncertainty."""
        return pd.DataFrame({"parameter": self.labels, "block": self.groups,
                             "unit": self.units, "value": self.values, "u": self.u})

    def residuals_frame(self) -> pd.DataFrame:
        """Residuals per observation with position, probe, ball and source."""
        t = self.table
        cols = [c for c in ("position", "probe", "ball", "source", "row", "time_min",
                            "temp_C") if c in t]
        out = t[cols].copy()
        out["rx_um"], out["ry_um"], out["rz_um"] = self.residuals_um.T
        return out


IMPLAUSIBLE = 1000.0
"""Size (µm or µrad) beyond which a fitted kinematic coefficient is not a CMM error: a
machine whose straightness or rotation errors reach a millimetre or a milliradian is
broken, so such values mean the data barely determine that function."""


def _message(status, it, rms, chi2_dof, null_words, chi2_p=1.0, dof=0, test_dof=None):
    head = {"converged": f"Converged in {it} iterations",
            "max_iterations": f"Stopped after {it} iterations without converging",
            "failed": "No step reduced the misfit"}[status]
    # an instrument-only fit has no plate residual to take an RMS of
    spread = f"RMS {rms:.3f} µm" if np.isfinite(rms) else "instruments only, no plate"
    msg = f"{head}: {spread}, χ²/dof {chi2_dof:.2f}."
    test_dof = chi2_dof if test_dof is None else test_dof
    if chi2_p < CHI2_ALPHA:
        cert = ("" if abs(test_dof - chi2_dof) < 0.005 else
                f" with the certificate's uncertainty counted (χ²/dof {test_dof:.2f})")
        msg += (f" It fails the χ² test{cert} ({p_text(chi2_p)} at {dof} degrees of freedom):"
                f" the scatter is {np.sqrt(test_dof):.2f} times what the stated repeatability"
                f"{' and certificate allow' if cert else ' allows'}, so the model misses "
                "something or σ is understated (run the diagnosis), and the uncertainties' "
                "noise part is too small by that factor (the Birge ratio).")
    if null_words:  # FitResult.null_words, each distinct sentence once
        said = list(dict.fromkeys(null_words))
        msg += (f" The data cannot determine {len(null_words)} parameter combination(s); they "
                "are held at the minimum-norm solution and reported as unidentifiable. "
                + " ".join(said[:3]) + (" ..." if len(said) > 3 else "")
                + " Add positions, heights or probe offsets that exercise them, or remove "
                "them from the model.")
    return msg
