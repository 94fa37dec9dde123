"""Is the plate certificate a suspect? Compare it with the plate the measurements imply.

With several placements the measurements determine the plate themselves
(self-calibration, thesis §6: ``plate="free"``) up to a translation, rotation and scale.
The certificate is then an observation like any other: fitting it as a prior (weighted by
its stated uncertainties) adds ``3B - 7`` independent rows to the free fit, and their χ²
is a test of the certificate as a whole (an F-test against the free fit's scatter, so
that an effect the model misses elsewhere does not count against the certificate). Each
coordinate's difference between the self-calibrated plate and the certificate, over their
combined uncertainty, names the entries at fault. Because a ball's plate coordinates are
shared by every placement, a ball off by the same amount in every placement is the
certificate, not the machine.

The fixes offered are the three ways of weighting the certificate: as a prior with its
stated uncertainties, free (self-calibration), and the prior with the suspect entries
released (``release``: no prior row for them).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import stats

from ..io import Dataset
from ..model import FitResult, Observations, fit, select

ALPHA = 0.01
"""False-alarm rate of the certificate test and, Bonferroni over every coordinate, of
naming an entry."""


@dataclass(frozen=True)
class CertificateCheck:
    """The certificate compared with the self-calibrated plate.

    Attributes
    ----------
    p_value : float
        F-test p-value of the certificate as a whole (prior rows against the free fit).
    suspect : bool
        True when ``p_value < ALPHA``.
    delta_chi2 : float
        χ² the certificate rows add to the self-calibrated fit.
    dof : int
        Independent certificate rows (3 per ball minus the 7 gauge freedoms).
    entries : list of dict
        Coordinates whose certificate value disagrees with the self-calibrated plate by
        more than the Bonferroni limit: ``ball, axis, deviation_um`` (self-calibrated minus
        certificate), ``u_um`` (combined standard uncertainty, the self-calibrated part
        scaled by the free fit's Birge ratio when above 1) and ``z``. Largest first.
    z_limit : float
        The |z| above which an entry is named.
    fixes : dict
        ``{name: {"plate", "release", "chi2_dof", "rms_um", "fails_chi2_test"}}`` for the
        certificate as fixed, as a prior, free, and as a prior with the named entries
        released.
    message : str
        Plain-language conclusion.
    """

    p_value: float
    suspect: bool
    delta_chi2: float
    dof: int
    entries: list = field(default_factory=list)
    z_limit: float = float("nan")
    fixes: dict = field(default_factory=dict)
    message: str = ""

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        return {"p_value": self.p_value, "suspect": self.suspect,
                "delta_chi2": self.delta_chi2, "dof": self.dof, "entries": self.entries,
                "z_limit": self.z_limit, "fixes": self.fixes, "message": self.message}


def released(obs: Observations, entries: Iterable[tuple[int, str]]) -> Observations:
    """Observations whose certificate has no prior on ``entries`` ((ball, axis) pairs):
    with ``plate="prior"`` those coordinates are fitted from the measurements alone."""
    if obs.cert_u_um is None:
        raise ValueError("the observations have no certificate to release entries of")
    u = obs.cert_u_um.copy()
    col = {b: i for i, b in enumerate(obs.balls)}
    for ball, axis in entries:
        if int(ball) in col:
            u[col[int(ball)], "xyz".index(axis)] = np.inf
    return replace(obs, cert_u_um=u)


def _summary(r: FitResult, release=()) -> dict:
    return {"plate": r.plate, "release": [f"ball {b} {a}" for b, a in release],
            "chi2_dof": r.chi2_dof, "rms_um": r.rms_um, "fails_chi2_test": r.fails_chi2_test,
            "status": r.status}


def check_certificate(data: Dataset | Observations, spec: str = "kinematic21", *, order: int = 2,
                  sigma_um: float = 0.5, exclude: Iterable[tuple[str, str, int]] = (),
                  positions: Sequence[str] | None = None, probes: Sequence[str] | None = None,
                  fitted: FitResult | None = None) -> CertificateCheck | None:
    """Test the certificate against the self-calibrated plate (module docstring).

    ``fitted`` is a fit of ``spec`` on the same observations and σ already at hand (the
    diagnosis's baseline); it is reused for its plate mode instead of fitted again.
    Returns None when there is no certificate or the design cannot self-calibrate the
    plate (the free fit leaves plate coordinates undetermined: one placement, say).
    """
    obs = data if isinstance(data, Observations) else select(
        data, positions=positions, probes=probes, exclude=exclude)
    if not obs.has_certificate or obs.cert_u_um is None:
        return None
    kw: dict[str, Any] = {"order": order, "sigma_um": sigma_um}
    have = {fitted.plate: fitted} if fitted is not None else {}

    def fit_plate(mode):
        return have[mode] if mode in have else fit(obs, spec, plate=mode, **kw)

    free = fit_plate("free")
    if any(lab.startswith("ball") for lab in free.unidentifiable) or free.dof <= 0:
        return None
    prior, fixed = fit_plate("prior"), fit_plate("fixed")
    B = len(obs.balls)
    dof = 3 * B - 7
    dchi2 = max(prior.chi2 - free.chi2, 0.0)
    s2 = free.chi2 / max(free.dof, 1)
    p = float(stats.f.sf((dchi2 / dof) / max(s2, 1e-300), dof, max(free.dof, 1)))
    labs, dev, u_free = free.block("plate")
    birge = max(1.0, free.birge_ratio)
    u_cert = obs.cert_u_um.ravel()
    u = np.sqrt((u_free * birge) ** 2 + u_cert**2)
    z = dev / u
    z_limit = float(stats.norm.isf(ALPHA / (2 * dev.size)))
    entries = []
    for i in np.argsort(-np.abs(np.nan_to_num(z))):
        if not abs(z[i]) > z_limit:
            break
        ball, axis = labs[i][4:].split(".")
        entries.append({"ball": int(ball), "axis": axis, "deviation_um": float(dev[i]),
                        "u_um": float(u[i]), "z": float(z[i])})
    release = [(e["ball"], e["axis"]) for e in entries]
    fixes = {"certificate fixed": _summary(fixed), "certificate as prior": _summary(prior),
             "self-calibrated (free)": _summary(free)}
    if release:
        rel = fit(released(obs, release), spec, plate="prior", **kw)
        fixes["prior, suspect entries released"] = _summary(rel, release)
    suspect = p < ALPHA
    if suspect:
        named = ", ".join(f"ball {e['ball']} {e['axis']} ({e['deviation_um']:+.1f} µm = "
                          f"{e['z']:+.1f} u)" for e in entries[:5])
        msg = (f"The certificate is a suspect: the plate the measurements imply disagrees "
               f"with it beyond its stated uncertainty (F-test p = {p:.2g}; χ² "
               f"{dchi2:.0f} on {dof} certificate rows). "
               + (f"Entries off in every placement alike: {named}"
                  + (f" and {len(entries) - 5} more" if len(entries) > 5 else "") + ". "
                  if entries else "No single entry stands out: the disagreement is spread "
                  "over the plate (a scale or form the certificate does not describe). ")
               + "χ²/dof with the certificate fixed "
               f"{fixed.chi2_dof:.2f}, as a prior {prior.chi2_dof:.2f}, self-calibrated "
               f"{free.chi2_dof:.2f}"
               + (f", suspect entries released {fixes['prior, suspect entries released']['chi2_dof']:.2f}"
                  if release else "") + ". An effect that deforms the plate's image alike in "
               "every placement (plate sag, the plate's temperature) looks the same: when a "
               "catalogue effect is significant too, add it first and check again.")
    else:
        msg = (f"The certificate agrees with the self-calibrated plate within its stated "
               f"uncertainty (F-test p = {p:.2g}).")
    return CertificateCheck(p, suspect, float(dchi2), int(dof), entries, z_limit, fixes, msg)
