"""What a plan will deliver, from its design alone: U1-U3, the error functions'
uncertainties, undetermined combinations, detection limits and time (``plan`` makes and
fits the plan's data; ``detect`` the detection limits).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .._blas import single_blas_thread
from ..model import FitResult
from ..model import evaluate as evaluate_u
from .detect import detection_limits
from .plans import STROKE_POINTS, Plan, design_fit


@dataclass(frozen=True)
class PlanEvaluation:
    """What a plan will deliver, from its design alone.

    Attributes
    ----------
    name : str
        Strategy name.
    n_obs : int
        Probed ball centres.
    undetermined : list of str
        Parameter combinations the data cannot determine, written as the fit writes them
        (any basis of that space is as valid: compare spaces, not strings).
    undetermined_parameters : list of str
        Parameters carrying weight in those combinations.
    undetermined_words : list of str
        The same combinations in words (``FitResult.null_words``).
    U1_um, U2_um, U3_um : dict or None
        Thesis U1 (ball centres; None with the plate fixed), U2 (evaluated region) and U3
        (working volume), average standard uncertainty per axis in µm; None when
        undetermined.
    functions : dict
        Error function -> ``{"unit", "at_mm", "u", "u_max"}``: standard uncertainty of
        the function at ``STROKE_POINTS`` points of its stroke (µm or µrad; None when the
        function is undetermined).
    detection_limits : dict
        Catalogue effect -> ``detect.DetectionLimit``.
    skipped : dict
        Effects the diagnosis would not try with these data, with the reason.
    time_min : float
        Measuring time in minutes.
    message : str
        What was evaluated and how.
    fit : FitResult
        The design fit (covariance, layout, null space).
    plan : Plan
        The plan evaluated.
    """

    name: str
    n_obs: int
    undetermined: list
    undetermined_parameters: list
    U1_um: dict | None
    U2_um: dict | None
    U3_um: dict | None
    functions: dict
    detection_limits: dict
    skipped: dict
    time_min: float
    message: str
    fit: FitResult = field(repr=False)
    plan: Plan | None = field(default=None, repr=False)
    undetermined_words: list = field(default_factory=list)

    @property
    def determined(self) -> bool:
        """True when the design determines every parameter of the model."""
        return not self.undetermined

    def expected_check(self) -> dict:
        """For each effect the plan's ``model.expected`` names (token or family, e.g.
        ``plate_sag`` or ``periodic_x``): ``{"expected", "limit", "unit", "detectable"}``
        (detectable: the expected size reaches the detection limit)."""
        exp = (self.plan.model.get("expected") or {}) if self.plan is not None else {}
        out = {}
        for tok, size in exp.items():
            lim = next((v for v in self.detection_limits.values()
                        if tok in (v.effect, v.family)), None)
            out[tok] = {"expected": size, "limit": None if lim is None or not np.isfinite(
                lim.size) else lim.size, "unit": None if lim is None else lim.unit,
                        "detectable": bool(lim is not None and size >= lim.size)}
        return out

    def _limits_dict(self) -> dict:
        exp = self.expected_check()
        out = {k: v.to_dict() for k, v in self.detection_limits.items()}
        for tok, rec in exp.items():
            key = next((k for k, v in self.detection_limits.items()
                        if tok in (v.effect, v.family)), None)
            if key is not None:
                out[key].update({"expected": rec["expected"], "detectable": rec["detectable"]})
        return out

    def to_dict(self) -> dict:
        """JSON-ready record (the ``strategies`` entries of ``plan``'s output)."""
        return {"name": self.name, "n_obs": self.n_obs, "undetermined": self.undetermined,
                "undetermined_words": self.undetermined_words,
                "undetermined_parameters": self.undetermined_parameters,
                "U1_um": self.U1_um, "U2_um": self.U2_um, "U3_um": self.U3_um,
                "detection_limits": self._limits_dict(),
                "skipped": self.skipped, "functions": self.functions,
                "expected_effects": self.expected_check(),
                "time_min": self.time_min, "message": self.message}


def function_uncertainty(result: FitResult, n: int = STROKE_POINTS) -> dict:
    """Standard uncertainty of every error function over its stroke, from the kinematic
    covariance: ``u(f(t)) = sqrt(b(t)ᵀ V_f b(t))`` with ``b`` the function's Chebyshev
    basis (thesis eq. 4.1-4.9 parameterisation) and ``V_f`` its coefficient block."""
    terms = result.terms
    cov = result.kinematic_cov
    bad = set(result.unidentifiable)
    out = {}
    for fn, sl in terms.slices.items():
        a = {"sxy": 1, "sxz": 2, "syz": 2}.get(fn, "xyz".index(fn[1]))
        t = np.linspace(0.0, float(terms.range_mm[a]), n)
        labels = terms.labels[sl]
        if any(lab in bad for lab in labels):
            u = None
        else:
            B = terms.design(fn, t)
            u = np.sqrt(np.clip(np.einsum("ik,kl,il->i", B, cov[sl, sl], B), 0, None))
        out[fn] = {"unit": "urad" if fn[0] in "rs" else "um", "at_mm": t.tolist(),
                   "u": None if u is None else u.tolist(),
                   "u_max": None if u is None else float(u.max())}
    return out


@single_blas_thread
def evaluate(plan: Plan, *, detection: bool = True, n_random: int = 200) -> PlanEvaluation:
    """Evaluate a plan from its design alone (module docstring).

    Parameters
    ----------
    plan : Plan
    detection : bool
        Compute the detection limit of every catalogue effect (``detect``).
    n_random : int
        Random points of U2 and U3 (thesis: 200).

    Returns
    -------
    PlanEvaluation
    """
    t0 = time.perf_counter()
    r = design_fit(plan)
    u = evaluate_u(r, n_random=n_random, seed=plan.seed)
    limits, skipped = {}, {}
    if detection:

        limits, skipped = detection_limits(r, plan)
    msg = (f"Evaluated from the design alone (noise-free virtual data, σ = "
           f"{plan.noise_um:g} µm) in {time.perf_counter() - t0:.2f} s. {u.message}")
    if r.null_combinations:
        msg += (f" The design leaves {len(r.null_combinations)} combination(s) undetermined:"
                " add placements or styli that exercise them, or remove those functions.")
    return PlanEvaluation(plan.name, r.n_obs, list(r.null_combinations),
                          list(r.unidentifiable), u.U1_um, u.U2_um, u.U3_um,
                          function_uncertainty(r), limits, skipped, plan.time_min, msg, r,
                          plan, list(r.null_words))
