"""Conformity of an interim check against the machine's MPE (ISO 14253-1 decision rule).

The lengths between balls on a common row, column or diagonal of the check's plate
(``gum.mpe``: error = measured minus certificate length) are decided one by one with the
uncertainty of the test as guard band (ISO 14253-1:2017 §5: conforms when
``|E| + U <= MPE``, does not conform when ``|E| - U > MPE``, else inconclusive). The
statement for the machine follows:

- *does not conform* when any length does not conform;
- *cannot say* when any length is inconclusive, when the plate is not square (no line
  pairs), or when the check cannot see part of the machine: the refit
  (``changes.what_changed``) finds combinations of the model's parameters the new data
  cannot determine (one placement sees no errors out of its plane): what was not measured
  is never declared conforming;
- *conforms* otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..export import Model
from ..gum import MpeResult, conformity_uncertainty_um, mpe_check
from ..io import DataError, Dataset
from .changes import Changes, what_changed
from .check import InterimCheck
from .unseen import unseen_example

STATEMENTS = ("conforms", "does not conform", "cannot say")
"""The machine-level statements of :func:`conformity`."""


@dataclass(frozen=True)
class Conformity:
    """Outcome of :func:`conformity`.

    Attributes
    ----------
    statement : str
        One of :data:`STATEMENTS`.
    message : str
        The statement, the decision rule and what the check could not see.
    counts : dict
        Lengths per ISO 14253-1 decision (``gum.mpe.DECISIONS``).
    mpe : MpeResult or None
        The length table; None when the plate has no line pairs (not square).
    rule : str
        The decision rule in words (for reports).
    unseen : list of str
        The parameter combinations the check cannot determine, in words
        (``Changes.unseen``).
    """

    statement: str
    message: str
    counts: dict
    mpe: MpeResult | None
    rule: str
    unseen: list

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        return {"statement": self.statement, "message": self.message,
                "counts": dict(self.counts), "rule": self.rule, "unseen": list(self.unseen)}


MPE_MAX_A_UM = 100.0
"""Largest constant term of a length MPE this reads (µm): the largest CMMs state a few
tens of µm; 600 is the length term written first."""
MPE_MIN_D = 10.0
"""Smallest D of the length term L/D (L in mm) this reads: L/10 is 100 µm per metre,
beyond any CMM; 0.6 is the constant term written second."""


def parse_mpe(text: str) -> tuple[float, float]:
    """The machine's MPE for lengths written ``"A,D"`` (ISO 10360-2 style, MPE = A µm +
    L/D with L in mm, e.g. ``"0.6,600"``) as ``(A, D)``; the CLI's ``--mpe`` and the
    app's field both read it here.

    Raises
    ------
    ValueError
        One line quoting the text when it is not two finite numbers with A >= 0 and
        D > 0 (``inf,600`` and ``nan,1`` are refused), or when they are not a CMM's
        (A above :data:`MPE_MAX_A_UM` µm or D below :data:`MPE_MIN_D`: the terms swapped,
        ``600,0.6``, or the length term written as µm per metre).
    """
    try:
        a, d = (float(v) for v in str(text).split(","))
    except ValueError:
        raise ValueError(f"expected 'A,D' (MPE = A µm + L/D), e.g. 0.6,600, found "
                         f"{str(text)[:40]!r}") from None
    if not (np.isfinite(a) and np.isfinite(d) and a >= 0 and d > 0):
        raise ValueError(f"expected 'A,D' with finite A >= 0 µm and D > 0, e.g. 0.6,600, "
                         f"found {str(text)[:40]!r}")
    if a > MPE_MAX_A_UM or d < MPE_MIN_D:
        raise ValueError(f"{str(text)[:40]!r} is not a CMM's MPE (A = {a:g} µm, L/{d:g}): "
                         f"expected A up to {MPE_MAX_A_UM:g} µm and D of {MPE_MIN_D:g} or "
                         f"more, e.g. 0.6,600" + (f"; did you mean {d:g},{a:g}?" if
                                                  d <= MPE_MAX_A_UM and a >= MPE_MIN_D
                                                  else ""))
    return a, d


RULE = ("ISO 14253-1 with the test's expanded uncertainty U (k = 2) as guard band: a length "
        "conforms when |E| + U <= MPE, does not conform when |E| - U > MPE, and is "
        "inconclusive otherwise")


def conformity(model: Model, check: InterimCheck, dataset: Dataset, *, mpe_a_um: float = 0.6,
               mpe_per_mm: float = 1.0 / 600.0, changes: Changes | None = None) -> Conformity:
    """The machine's conformity to ``MPE = a + L·per_mm`` from an interim check's data.

    Parameters
    ----------
    model : Model
        The stored calibration of the check.
    check : InterimCheck
        :func:`interim_check` of ``dataset`` against ``model``.
    dataset : Dataset
        The check's measurements with the plate's certificate.
    mpe_a_um, mpe_per_mm : float
        The machine's MPE for length measurement, ``a + L · per_mm`` (L in mm); default
        the thesis's 0.6 µm + L/600 (thesis §6.2).
    changes : Changes, optional
        :func:`what_changed` of the check (computed when not given).

    Returns
    -------
    Conformity
    """
    changes = what_changed(model, check) if changes is None else changes
    cert = dataset.certificate
    if cert is None:  # the interim check refuses such data already; a direct call too
        raise DataError("a conformity statement needs the plate's certificate; found none.",
                        file=dataset.name, hint="load the certificate with the data.")
    n = int(round(np.sqrt(len(cert.balls))))
    mpe = None
    if n * n == len(cert.balls) and n >= 2:
        tables = {}
        left_out = 0
        for pos in check.positions:
            at = check.table[check.table.position == pos]
            for prb in dict.fromkeys(at["probe"]):
                tab = dataset.plate_frame_table(pos, prb)
                # a ball the check's fit left out (an exclusion) gives no length either
                used = np.isin(cert.balls, at.loc[at.probe == prb, "ball"].to_numpy())
                measured = np.isfinite(tab).all(axis=1)
                tab[~used] = np.nan
                if measured.all():  # a table with an unmeasured ball gives no length
                    left_out += int(np.sum(~used))
                    tables[f"{pos}/{prb}"] = tab
        if tables:
            sig = check.sigma_um
            mpe = mpe_check(tables, cert.xyz_mm, n=n, mpe_a_um=mpe_a_um,
                            mpe_per_mm=mpe_per_mm,
                            uncertainty=lambda L: conformity_uncertainty_um(L, sig))
    counts = dict(mpe.counts) if mpe is not None else {}
    limit = f"MPE = {mpe_a_um:g} µm + L/{1 / mpe_per_mm:g} (L in mm)"
    if mpe is not None and left_out:
        note = (f" The lengths to the {left_out} ball measurement(s) the check's fit "
                     "left out (exclusions) are not counted.")
    else:
        note = ""
    if mpe is None:
        statement = "cannot say"
        msg = (f"Cannot say whether the machine conforms to {limit}: the check's plate has no "
               "complete square grid of balls to take lengths from.")
    elif counts.get("does not conform", 0):
        statement = "does not conform"
        msg = (f"Does not conform to {limit}: {counts['does not conform']} of "
               f"{len(mpe.error_um)} lengths exceed it beyond their uncertainty.")
    elif counts.get("inconclusive", 0):
        statement = "cannot say"
        msg = (f"Cannot say whether the machine conforms to {limit}: {counts['inconclusive']} "
               f"of {len(mpe.error_um)} lengths are within their uncertainty of it "
               "(inconclusive).")
    elif changes.unseen:
        statement = "cannot say"
        msg = (f"The {len(mpe.error_um)} lengths measured conform to {limit}, but the check "
               f"cannot see {len(changes.unseen)} combination(s) of the machine's errors "
               f"(e.g. {unseen_example(changes.unseen)}): it cannot say that the machine "
               "conforms.")
    else:
        statement = "conforms"
        msg = (f"Conforms to {limit}: all {len(mpe.error_um)} lengths, and the check sees "
               "every parameter of the stored model.")
    return Conformity(statement, f"{msg}{note} Decision rule: {RULE}.", counts, mpe, RULE,
                      list(changes.unseen))
