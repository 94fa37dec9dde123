"""The fewest changes that explain an interim check's data, in physical terms first.

:func:`.changes.what_changed` tests every parameter of the stored model; on a machine
whose scales are 1.5 K warm (a common 17 ppm) it lists squareness and rotations among
the parameters that "moved", because one placement's data let a scale change leak into
them. A metrologist asks the other question: which *one* change, or which few, explain
what the new data show? This module answers it the way the diagnosis finds effects:
nested tests, forward, at a stated family-wise level.

The model is the check's own (:func:`change_system`, the system of
``what_changed``): the score ``g = -Jᵀ Π d`` and information ``H = Jᵀ Π J`` of the change
``δ`` of the kinematic coefficients (and, with two styli or more, of the styli's
offsets), with the stored model's uncertainty and the poses already in ``Π``; if nothing
changed ``g ~ N(0, H)``, and a
change ``δ = X θ`` (``X``: a hypothesis's columns, in the units of its physical
parameters) shifts it to ``N(H X θ, H)``. A hypothesis set ``S`` explains

    χ²(S) = gᵀ X_S (X_Sᵀ H X_S)⁺ X_Sᵀ g,

``χ²(S ∪ b) - χ²(S) ~ χ²_q`` (q the rank it adds) when ``S`` is the whole change (the
nested test of a Gaussian linear model; Rao 1973 §4b). The hypotheses, physical first:

- with the scales' temperatures recorded in the new data (``temp_x_C``, ``temp_y_C``,
  ``temp_z_C``), their **thermal expansion** (``machine_thermal``): each axis's scale
  changed by ``κ (T_a - 20 °C)``, one number κ in ppm/K over the axes' mean recorded
  temperatures, named first (with every axis equally warm it is the common scale below,
  said in its physical cause);
- a **common scale** of the three axes (one number, ppm: warm scales, a wrong expansion
  coefficient, a wrong temperature compensation);
- each axis's **scale** alone (ppm);
- each **squareness** (µrad);
- each other **error function** whole (all its coefficients), named in ISO 230-1's
  words (:func:`.unseen.unseen_words`).

Forward selection: at each step the hypothesis with the smallest p-value of its nested
test is added when ``p · m <= alpha`` (Bonferroni over the ``m`` hypotheses tried at that
step; the first step holds the family-wise false-alarm level ``alpha`` on an unchanged
machine); it stops when none passes. A hypothesis the new data hardly resolve (every one
of its columns below :data:`.changes.MIN_RESOLVED` of its prior variance when moving
alone) is never tried: it is never headlined. A hypothesis that explains the step's
χ² within :data:`ALIAS_CHI2` of the chosen one and adds nothing significant after it
is reported as its alias ("or equally").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg, stats

from ..export import Model
from ..machine import ERROR_NAMES, POSITIONING, ROTATIONAL, SQUARENESS
from ..units import p_text
from .changes import MIN_RESOLVED, projected
from .check import InterimCheck
from .unseen import unseen_words

ALIAS_CHI2 = stats.chi2.ppf(0.95, 1)
"""A rival hypothesis explaining the step's χ² within this much of the chosen one (3.84:
the 95 % point of χ²₁, a likelihood ratio of e^1.92) is named as its alias."""

@dataclass(frozen=True)
class Hypothesis:
    """One physical change the new data may show."""

    key: str
    """Short name (``scale``, ``x_scale``, ``sxy``, ``rxz``)."""
    words: str
    """What it is, in a metrologist's words."""
    columns: np.ndarray
    """``(n_labels, q)``: the change of the kinematic coefficients per unit of each of
    its parameters."""
    units: tuple[str, ...]
    """The unit of each parameter (``ppm``, ``µrad``, ``µm``)."""
    names: tuple[str, ...]
    """Each parameter's name (a label, or ``scale``)."""
    function: str
    """The error function it is a form of (``dxx`` for the x scale, ``rxz`` for its
    linear term; ``scale`` for the common scale): forms of one function are nested, not
    aliases."""


@dataclass(frozen=True)
class Step:
    """One hypothesis added by the forward selection."""

    hypothesis: Hypothesis
    """The change added."""
    chi2: float
    """χ² it explains on top of the steps before it."""
    dof: int
    """Rank it adds."""
    p_value: float
    """p-value of its nested test."""
    tried: int
    """Hypotheses tried at this step (the Bonferroni count)."""
    values: tuple[float, ...]
    """Its parameters' estimates, in :attr:`Hypothesis.units`, fitted with the hypotheses
    chosen before it."""
    u: tuple[float, ...]
    """Their standard uncertainties (the stored model's uncertainty and the noise)."""
    aliases: tuple[str, ...]
    """Words of the hypotheses that explain the same within :data:`ALIAS_CHI2`."""

    def text(self) -> str:
        """``a common scale change of all three axes: +17.1 ± 0.4 ppm``."""
        parts = [f"{'' if len(self.values) == 1 and n != 'κ' else n + ' = '}"
                 f"{_value_u(v, s, unit)}"
                 for n, v, s, unit in zip(self.hypothesis.names, self.values, self.u,
                                          self.hypothesis.units, strict=True)]
        alias = (f" (or, as well explained, {' or '.join(self.aliases)})"
                 if self.aliases else "")
        return f"{self.hypothesis.words}: {', '.join(parts)}{alias}"


@dataclass(frozen=True)
class ChangeExplanation:
    """Outcome of :func:`explain_change`."""

    message: str
    """The fewest changes that explain the new data, in one paragraph (empty steps: none
    is needed at the level)."""
    steps: tuple[Step, ...]
    """The hypotheses added, in order."""
    chi2_total: float
    """The check's χ² of the change (``gᵀ H⁺ g``: everything the kinematic parameters
    could explain)."""
    dof_total: int
    """Its degrees of freedom (the rank of ``H``)."""
    chi2_left: float
    """What the chosen changes leave of it."""
    dof_left: int
    """Its degrees of freedom."""
    p_left: float
    """p-value of what is left (small: a change the hypotheses do not cover remains)."""
    alpha: float
    """The family-wise level of the selection."""

    @property
    def first(self) -> Step | None:
        """The change named first (None when none is needed)."""
        return self.steps[0] if self.steps else None

    def to_dict(self) -> dict:
        """JSON-ready (the results' ``explanation``)."""
        return {"message": self.message, "alpha": self.alpha,
                "steps": [{"change": s.hypothesis.key, "words": s.hypothesis.words,
                           "parameters": [{"name": n, "value": float(v), "u": float(u),
                                           "unit": unit}
                                          for n, v, u, unit in zip(
                                              s.hypothesis.names, s.values, s.u,
                                              s.hypothesis.units, strict=True)],
                           "chi2": s.chi2, "dof": s.dof, "p_value": s.p_value,
                           "tried": s.tried, "aliases": list(s.aliases)}
                          for s in self.steps],
                "chi2_total": self.chi2_total, "dof_total": self.dof_total,
                "chi2_left": self.chi2_left, "dof_left": self.dof_left,
                "p_left": self.p_left}


def hypotheses(model: Model, scale_temps_C: dict | None = None) -> list[Hypothesis]:
    """The physical changes tried, in the order named by the module docstring, each
    built on the stored model's labels (those of its functions it has).

    ``scale_temps_C``: axis (``"x"``) -> mean recorded temperature of its scale in the
    new data (°C), for the thermal hypothesis; without it none is tried."""
    labels = list(model.terms.labels)
    n = len(labels)
    rng = dict(zip("xyz", model.terms.range_mm, strict=True))
    out = []
    scale_cols = {}
    for f in POSITIONING:
        lab = f"{f}[1]"
        if lab in labels:
            col = np.zeros(n)
            col[labels.index(lab)] = float(rng[f[1]]) / 2000.0  # µm of dAA[1] per ppm
            scale_cols[f[1]] = col
    warm = {a: float(t) - 20.0 for a, t in (scale_temps_C or {}).items()
            if a in scale_cols and np.isfinite(t)}
    if warm and any(abs(d) > 0 for d in warm.values()):
        temps = ", ".join(f"{a} {20 + d:.2f}" for a, d in warm.items())
        out.append(Hypothesis(
            "machine_thermal", f"the scales' thermal expansion (machine_thermal: their "
            f"recorded temperatures {temps} °C, {_axes(''.join(warm))} each changed by "
            "κ × (T − 20 °C))", np.sum([d * scale_cols[a] for a, d in warm.items()],
                                       axis=0).reshape(-1, 1), ("ppm/K",), ("κ",),
            "scale"))
    if len(scale_cols) > 1:
        axes = "".join(scale_cols)
        out.append(Hypothesis("scale", f"a common scale change of the {_axes(axes)} "
                              "scales (their temperature, expansion coefficient or "
                              "compensation)", np.sum(list(scale_cols.values()), axis=0)
                              .reshape(-1, 1), ("ppm",), ("scale",), "scale"))
    for a, col in scale_cols.items():
        out.append(Hypothesis(f"{a}_scale", f"the {a} scale", col.reshape(-1, 1), ("ppm",),
                              ("scale",), f"d{a}{a}"))
    for f in ROTATIONAL:  # a rotation growing along its axis: one number, as a scale
        lab = f"{f}[1]"
        if lab in labels and sum(x.partition("[")[0] == f for x in labels) > 1:
            col = np.zeros((n, 1))
            col[labels.index(lab)] = 1.0
            out.append(Hypothesis(f"{f}_linear", unseen_words(col.T, labels)[0], col,
                                  ("µrad",), (lab,), f))
    for f in ERROR_NAMES:
        idx = [j for j, lab in enumerate(labels)
               if lab == f or lab.partition("[")[0] == f]
        if not idx:
            continue
        cols = np.zeros((n, len(idx)))
        cols[idx, range(len(idx))] = 1.0
        direction = cols.sum(axis=1)
        words = unseen_words(direction.reshape(1, -1), labels)[0]
        units = tuple("µrad" if model.terms.unit(labels[j]) == "urad" else "µm"
                      for j in idx)
        out.append(Hypothesis(f, words if f not in SQUARENESS else f"the {f[1:]} "
                              f"squareness ({f})", cols, units,
                              tuple(labels[j] for j in idx), f))
    return out


def _axes(axes: str) -> str:
    """``x, y and z``."""
    return axes if len(axes) == 1 else ", ".join(axes[:-1]) + " and " + axes[-1]


def _value_u(v: float, u: float, unit: str) -> str:
    """``+17.32 ± 0.49 ppm``: the value to the decimals of its u at two digits."""
    if not (np.isfinite(u) and u > 0):
        return f"{v:+.3g} {unit} (u not determinable)"
    dec = max(0, 1 - int(np.floor(np.log10(u))))
    return f"{v:+.{dec}f} ± {u:.{dec}f} {unit}"


def _explained(g: np.ndarray, H: np.ndarray, X: np.ndarray) -> tuple[float, int,
                                                                       np.ndarray,
                                                                       np.ndarray]:
    """(χ² explained, rank, estimate, covariance) of the change ``δ = X θ``."""
    info = X.T @ H @ X
    info = (info + info.T) / 2
    w, Q = np.linalg.eigh(info)
    keep = w > max(w.max(initial=0.0), 0.0) * 1e-10
    if not keep.any():
        return 0.0, 0, np.zeros(X.shape[1]), np.full((X.shape[1],) * 2, np.inf)
    inv = (Q[:, keep] / w[keep]) @ Q[:, keep].T  # pseudo-inverse on the resolved span
    b = X.T @ g
    theta = inv @ b
    return float(b @ theta), int(keep.sum()), theta, inv


def _resolved(h: Hypothesis, H: np.ndarray, V: np.ndarray) -> bool:
    """Some column of the hypothesis resolved, moving alone, to at least
    :data:`MIN_RESOLVED` of its prior variance (the rule of ``what_changed``); a stylus
    offset, which has no prior in the model file, when its u is below
    :data:`STYLUS_U_MAX_UM`."""
    for x in h.columns.T:
        prior = float(x @ V @ x)
        info = float(x @ H @ x)
        if h.function == "stylus":
            if info > 0 and info ** -0.5 <= STYLUS_U_MAX_UM:
                return True
        elif prior > 0 and info * prior >= MIN_RESOLVED:
            return True
    return False


STYLUS_U_MAX_UM = 5.0
"""A stylus's offset change is tried when the new data give it, alone, a standard
uncertainty of at most this (µm): a stylus measured alone in its placement leaves its
offset to the pose (infinite u), and is never headlined."""


@dataclass(frozen=True)
class ChangeSystem:
    """The linear system the hypotheses of an interim check are tested in: the
    kinematic change ``δ`` and, with two styli or more, the styli's offset errors ``p``
    (3 per stylus, µm; the ``probe_offset`` convention of the simulator and the
    diagnosis), ``θ = (δ, p)``."""

    weights: np.ndarray
    """``W`` (rows of the check's system × θ): the score is ``Wᵀ d``; ``-Π J`` for δ and
    ``Π S`` for p (``S``: minus-identity blocks on each stylus's plate readings, whose
    residuals move by ``-p_q``), ``Π`` the check's pose-projected precision."""
    score: np.ndarray
    """``g = Wᵀ d``, ``N(H θ, H)`` (``N(0, H)`` if nothing changed)."""
    information: np.ndarray
    """``H``: ``Jᵀ Π J`` for δ (what ``what_changed`` tests), ``Sᵀ Π S`` for p, and
    ``-Jᵀ Π S`` between them."""
    prior: np.ndarray
    """The stored model's covariance of δ, zero for p (the model file has none)."""
    hypotheses: tuple
    """The :class:`Hypothesis` tried, on θ."""


def change_system(model: Model, check: InterimCheck, *,
                  scale_temps_C: dict | None = None) -> ChangeSystem:
    """The system :func:`explain_change` selects in (:class:`ChangeSystem`)."""
    sys_ = check.system
    J = sys_.J
    obs = sys_.obs
    styli = [str(q) for q in obs.probes] if obs is not None and len(obs.probes) >= 2 \
        else []
    n_k, n_p = J.shape[1], 3 * len(styli)
    S = np.zeros((len(sys_.d_um), n_p))
    if styli:
        n_plate = sys_.n_plate_rows if sys_.n_plate_rows >= 0 else len(sys_.d_um)
        for i, q in enumerate(obs.probe[: n_plate // 3]):
            S[3 * i:3 * i + 3, 3 * q:3 * q + 3] = -np.eye(3)
    Z = np.hstack([-J, S])  # how each θ enters d
    W = projected(check, Z)
    H = Z.T @ W
    H = (H + H.T) / 2
    V = linalg.block_diag(model.cov, np.zeros((n_p, n_p)))
    pool = [Hypothesis(h.key, h.words, np.vstack([h.columns,
                                                  np.zeros((n_p, h.columns.shape[1]))]),
                       h.units, h.names, h.function)
            for h in hypotheses(model, scale_temps_C)]
    for j, q in enumerate(styli):
        # a bent or replaced stylus is named as such, not as the rotations that mimic it
        cols = np.zeros((n_k + n_p, 3))
        cols[n_k + 3 * j:n_k + 3 * j + 3] = np.eye(3)
        pool.append(Hypothesis(f"stylus_{q}", f"stylus {q}'s offset (bent, replaced or "
                               "requalified)", cols, ("µm",) * 3,
                               tuple(f"{q}.{a}" for a in "xyz"), "stylus"))
    return ChangeSystem(W, W.T @ sys_.d_um, H, V, tuple(pool))


def explain_change(model: Model, check: InterimCheck, *,
                   alpha: float = 0.05, max_steps: int = 4,
                   scale_temps_C: dict | None = None) -> ChangeExplanation:
    """The fewest physical changes that explain the new data (module docstring).

    Parameters
    ----------
    model : Model
        The stored calibration.
    check : InterimCheck
        The check of the new data against it.
    alpha : float
        Family-wise false-alarm level of the first step (Bonferroni at each step).
    max_steps : int
        At most this many changes are named.
    scale_temps_C : dict, optional
        Axis -> mean recorded temperature of its scale in the new data (°C): the
        thermal hypothesis (:func:`hypotheses`).

    Returns
    -------
    ChangeExplanation
    """
    cs = change_system(model, check, scale_temps_C=scale_temps_C)
    return select_changes(cs.score, cs.information, cs.prior, list(cs.hypotheses),
                          alpha=alpha, max_steps=max_steps)


def explain_difference(m1: Model, m2: Model, *, alpha: float = 0.05,
                       max_steps: int = 4) -> ChangeExplanation:
    """The fewest physical changes between two calibrations of one machine.

    Their difference on the parameters both have, ``Δ = c₂ - c₁``, is ``N(δ, V₁ + V₂)``
    for independent calibrations (JCGM 100 eq. 13 with their full covariances): the
    score of a change is ``g = W Δ`` and its information ``H = W`` with ``W = (V₁ +
    V₂)⁺``, and the hypotheses of :func:`hypotheses` (on ``m1``'s labels, restricted to
    the shared ones) are selected as by :func:`explain_change`.
    """
    common = [lab for lab in m1.terms.labels if lab in set(m2.terms.labels)]
    i1 = [m1.terms.labels.index(lab) for lab in common]
    i2 = [m2.terms.labels.index(lab) for lab in common]
    V, _ = difference_covariance(m1, m2, i1, i2)
    W = np.linalg.pinv((V + V.T) / 2, hermitian=True)
    delta = m2.coef[i2] - m1.coef[i1]
    pool = []
    for h in hypotheses(m1):
        cols = h.columns[i1]
        if np.any(cols):
            pool.append(Hypothesis(h.key, h.words, cols, h.units, h.names, h.function))
    return select_changes(W @ delta, W, V, pool, alpha=alpha, max_steps=max_steps)


def shares_certificate(m1: Model, m2: Model) -> bool:
    """Both calibrations were fitted with the plate fixed to one certificate (the same
    digest and balls in their model files)."""
    c1, c2 = m1.certificate, m2.certificate
    return bool(c1 and c2 and c1["digest"] == c2["digest"] and c1["balls"] == c2["balls"])


def difference_covariance(m1: Model, m2: Model, i1, i2) -> tuple[np.ndarray, bool]:
    """``(cov(c₂ − c₁), shared)`` on the coefficients ``i1`` of ``m1`` and ``i2`` of
    ``m2``: ``V₁ + V₂`` for independent calibrations (JCGM 100 eq. 13), less the
    covariance their shared certificate errors give both, ``S₁ S₂ᵀ + S₂ S₁ᵀ``, when they
    were made with one certificate (:func:`shares_certificate`; ``shared`` says so):
    those errors move both calibrations alike and cancel in their difference."""
    V = m1.cov[np.ix_(i1, i1)] + m2.cov[np.ix_(i2, i2)]
    if not shares_certificate(m1, m2):
        return V, False
    assert m1.certificate is not None and m2.certificate is not None  # shares_certificate
    C = (np.asarray(m1.certificate["sensitivity"])[i1]
         @ np.asarray(m2.certificate["sensitivity"])[i2].T)
    return V - C - C.T, True


def select_changes(g: np.ndarray, H: np.ndarray, V: np.ndarray,
                   candidates: list[Hypothesis], *, alpha: float = 0.05,
                   max_steps: int = 4) -> ChangeExplanation:
    """Forward selection of the hypotheses that explain a score ``g ~ N(H δ, H)``
    (module docstring); ``V`` the prior covariance the resolution rule reads."""
    if not 0 < alpha < 0.5:
        raise ValueError(f"alpha must be in (0, 0.5), got {alpha}.")
    total, rank, _, _ = _explained(g, H, np.eye(len(g)))
    pool = [h for h in candidates if _resolved(h, H, V)]
    chosen: list[Hypothesis] = []
    steps: list[Step] = []
    have = 0.0
    have_rank = 0
    while pool and len(steps) < max_steps:
        base = [h.columns for h in chosen]
        trials = []
        for order, h in enumerate(pool):
            c2, r, _, _ = _explained(g, H, np.hstack([*base, h.columns]))
            d, q = c2 - have, r - have_rank
            if q > 0:
                trials.append((float(stats.chi2.sf(max(d, 0.0), q)), q, -d, h, d, order))
        if not trials:
            break
        trials.sort(key=lambda t: (t[0], t[1], t[2]))
        # hypotheses that explain the same to rounding (the thermal expansion of equally
        # warm scales is the common scale): the one listed first, the physical cause,
        # whatever the last digits say
        top = trials[0]
        tied = [t for t in trials if t[1] == top[1]
                and abs(t[4] - top[4]) <= 1e-9 * max(1.0, abs(top[4]))]
        first = min(tied, key=lambda t: t[5])
        trials.remove(first)
        trials.insert(0, first)
        p, q, _, best, gain, _ = first
        if p * len(trials) > alpha:
            break
        X = np.hstack([*base, best.columns])
        c2, r, theta, cov = _explained(g, H, X)
        k = best.columns.shape[1]
        est, u = theta[-k:], np.sqrt(np.clip(np.diag(cov)[-k:], 0, None))
        aliases = []
        for _, _, _, h, d2, _ in trials[1:]:
            if d2 < gain - ALIAS_CHI2 or h.function == best.function:
                continue  # a nested form of the same function is not an alias
            after, r2, _, _ = _explained(g, H, np.hstack([X, h.columns]))
            q2 = r2 - r
            if q2 <= 0 or stats.chi2.sf(max(after - c2, 0.0), q2) * len(trials) > alpha:
                aliases.append(h.words)
        chosen.append(best)
        pool = [h for h in pool if h is not best]
        steps.append(Step(best, float(gain), int(q), float(p), len(trials),
                          tuple(float(v) for v in est), tuple(float(s) for s in u),
                          tuple(aliases[:2])))
        have, have_rank = c2, r
    left, dof_left = max(total - have, 0.0), max(rank - have_rank, 0)
    p_left = float(stats.chi2.sf(left, dof_left)) if dof_left else 1.0
    return ChangeExplanation(_message(steps, left, dof_left, p_left, alpha), tuple(steps),
                             float(total), int(rank), float(left), int(dof_left), p_left,
                             float(alpha))


def _message(steps, left, dof_left, p_left, alpha) -> str:
    if not steps:
        return (f"No single change of the machine's geometry explains the new data at "
                f"the family-wise level {100 * alpha:g} %.")
    named = "; then ".join(s.text() for s in steps)
    rest = (f"nothing more is needed (what is left: χ² = {left:.1f} for {dof_left} "
            f"degrees of freedom, {p_text(p_left)})" if p_left >= alpha else
            f"a change none of these names remains (χ² = {left:.1f} for {dof_left} "
            f"degrees of freedom, {p_text(p_left)})")
    n = "change explains" if len(steps) == 1 else f"{len(steps)} changes explain"
    return (f"The fewest changes that explain the new data (nested tests, family-wise "
            f"level {100 * alpha:g} %): {named}. This {n} what the check sees; {rest}.")
