"""MPE check of ball-plate lengths (thesis §6.2 / appendix 1 specification, ISO 14253-1).

Every pair of balls on a common row, column or diagonal of the 5 x 5 plate gives a length;
its error is the measured minus the certificate length. The CMM specification (thesis §6.2,
appendix 1) is the maximum permissible error ``MPE = 0.6 µm + L/600`` (L in mm) and the
measurement uncertainty ``U(L) = sqrt(0.52² + (1.4e-3 L)²)`` µm (k = 2). Conformity is decided
by ISO 14253-1 (decision rule with the uncertainty as guard band):

- conforms: ``|E| + U <= MPE``;
- does not conform: ``|E| - U > MPE``;
- inconclusive otherwise (the interval |E| ± U straddles the limit).

Ball numbering is row-major (thesis figure 6.8): balls 1-5 form the first row along the plate
x axis, ball 21 starts the last row. Functions take arrays; reading files is
:mod:`cmm_core.io`'s job.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from ..io import Certificate, Dataset

DECISIONS = ("conforms", "does not conform", "inconclusive")
"""Possible ISO 14253-1 decisions."""

DIRECTIONS = ("row", "column", "diagonal", "antidiagonal")
"""Line types: row (along plate x), column (along plate y), diagonal (x and y increase
together, e.g. balls 1-7-13-19-25), antidiagonal (balls 5-9-13-17-21)."""


def mpe_um(length_mm: ArrayLike, a_um: float = 0.6, per_mm: float = 1.0 / 600.0) -> np.ndarray:
    """MPE = 0.6 µm + L/600 with L in mm (thesis §6.2)."""
    return a_um + per_mm * np.asarray(length_mm, float)


def uncertainty_um(length_mm: ArrayLike, a_um: float = 0.52, b_per_mm: float = 1.4e-3) -> np.ndarray:
    """U(L) = sqrt(0.52² + (1.4e-3 L)²) µm, k = 2 (thesis §6.2, appendix 1)."""
    L = np.asarray(length_mm, float)
    return np.sqrt(a_um**2 + (b_per_mm * L) ** 2)


def conformity_uncertainty_um(length_mm: ArrayLike, sigma_um: float, a_um: float = 0.26,
                        b_per_mm: float = 1.9e-3) -> np.ndarray:
    """Expanded (k = 2) uncertainty of a length error E = L_measured − L_certificate from
    the test itself: the plate's calibrated length, U = sqrt(a² + (b L)²) µm (k = 2, thesis
    appendix 1 plate specification), and the repeatability of the two probed centres
    (σ per coordinate, so σ√2 on their distance). ISO 14253-1 asks for the uncertainty of
    the measurement that decides conformity, not the machine's own specification."""
    L = np.asarray(length_mm, float)
    u_plate = np.sqrt(a_um**2 + (b_per_mm * L) ** 2) / 2
    return 2 * np.sqrt(u_plate**2 + 2 * float(sigma_um) ** 2)


def decide(error_um: ArrayLike, U_um: ArrayLike, mpe_limit_um: ArrayLike) -> np.ndarray:
    """ISO 14253-1 decision per length: 'conforms', 'does not conform' or 'inconclusive'."""
    e = np.abs(np.asarray(error_um, float))
    U = np.asarray(U_um, float)
    m = np.asarray(mpe_limit_um, float)
    return np.where(e + U <= m, DECISIONS[0], np.where(e - U > m, DECISIONS[1], DECISIONS[2]))


def line_pairs(n: int = 5, diagonals: str = "all") -> list[tuple[int, int, str]]:
    """Ball pairs (1-based, a < b) lying on a common row, column or diagonal of an n x n plate.

    Parameters
    ----------
    n : int
        Balls per side (row-major numbering, ball ``i*n + j + 1`` in row i, column j).
    diagonals : {'all', 'main', 'none'}
        'all': every 45° line; 'main': the two corner-to-corner diagonals only.

    Returns
    -------
    list of (ball_a, ball_b, direction)
        For n = 5: 50 row, 50 column and 30 + 30 diagonal pairs ('all') or 10 + 10 ('main').
    """
    if diagonals not in ("all", "main", "none"):
        raise ValueError(f"diagonals: expected 'all', 'main' or 'none', got {diagonals!r}.")
    n = int(n)
    if n < 2:
        raise ValueError(f"n: expected at least 2 balls per side, got {n}.")

    def ball(i, j):
        return i * n + j + 1

    out = []
    for (i1, j1), (i2, j2) in itertools.combinations(
            [(i, j) for i in range(n) for j in range(n)], 2):
        di, dj = i2 - i1, j2 - j1
        if di == 0:
            d = "row"
        elif dj == 0:
            d = "column"
        elif di == dj:
            d = "diagonal"
            if diagonals == "none" or (diagonals == "main" and i1 != j1):
                continue
        elif di == -dj:
            d = "antidiagonal"
            if diagonals == "none" or (diagonals == "main" and i1 + j1 != n - 1):
                continue
        else:
            continue
        out.append((ball(i1, j1), ball(i2, j2), d))
    return out


@dataclass(frozen=True)
class MpeResult:
    """Table of the MPE check and its counts (one row per position and ball pair)."""

    position: np.ndarray
    """Position name of each row."""
    ball_a: np.ndarray
    """First ball (1-based)."""
    ball_b: np.ndarray
    """Second ball (1-based)."""
    direction: np.ndarray
    """'row', 'column', 'diagonal' or 'antidiagonal'."""
    length_mm: np.ndarray
    """Certificate length between the two balls, mm."""
    error_um: np.ndarray
    """Measured minus certificate length, µm."""
    U_um: np.ndarray
    """Measurement uncertainty U(L) (k=2), µm."""
    mpe_um: np.ndarray
    """MPE limit at L, µm."""
    decision: np.ndarray
    """ISO 14253-1 decision."""
    counts: dict = field(default_factory=dict)
    """Number of rows per decision over all positions."""
    counts_by_position: dict = field(default_factory=dict)
    """{position: {decision: count}}."""

    def rows(self) -> list[dict]:
        """The table as a list of dicts (JSON-ready)."""
        return [{"position": str(p), "ball_a": int(a), "ball_b": int(b), "direction": str(d),
                 "length_mm": float(L), "error_um": float(e), "U_um": float(u),
                 "mpe_um": float(m), "decision": str(c)}
                for p, a, b, d, L, e, u, m, c in zip(
                    self.position, self.ball_a, self.ball_b, self.direction, self.length_mm,
                    self.error_um, self.U_um, self.mpe_um, self.decision, strict=True)]

    def max_abs_error_um(self) -> float:
        """Largest |error| over the table."""
        return float(np.max(np.abs(self.error_um))) if self.error_um.size else float("nan")


def _as_points(a, what: str, n_balls: int, missing: bool = False) -> np.ndarray:
    """``a`` as an (n_balls, 3) array of finite ball centres (``missing``: a ball may be
    NaN in all three coordinates, not measured or left out)."""
    arr = np.asarray(a, dtype=float)
    if arr.shape != (n_balls, 3):
        raise ValueError(f"{what}: expected a ({n_balls}, 3) array of ball centres in mm, got "
                         f"shape {arr.shape}.")
    bad = ~np.isfinite(arr)
    if missing:  # a missing ball is NaN in all three coordinates, never in one
        bad &= ~np.isnan(arr).all(axis=1, keepdims=True)
    if bad.any():
        bad = int(np.argwhere(bad)[0, 0]) + 1
        raise ValueError(f"{what}: expected finite coordinates, ball {bad} is not finite.")
    return arr


def mpe_check(tables: Mapping[str, np.ndarray], certificate: ArrayLike, *, n: int = 5,
              diagonals: str = "all", mpe_a_um: float = 0.6, mpe_per_mm: float = 1.0 / 600.0,
              U_a_um: float = 0.52, U_b_per_mm: float = 1.4e-3,
              uncertainty: Callable | None = None) -> MpeResult:
    """Length errors of every position against the MPE, with the ISO 14253-1 decision.

    Parameters
    ----------
    tables : mapping of str to (n*n, 3) array
        Measured ball centres per position, mm, plate frame, ball order 1..n*n; a ball
        not measured or left out (an excluded outlier) is NaN, and its lengths are not
        counted.
    certificate : (n*n, 3) array
        Calibrated ball centres, mm.
    n : int
        Balls per side (5 for the thesis plate).
    diagonals : {'all', 'main', 'none'}
        Which diagonal pairs to include (see :func:`line_pairs`).
    mpe_a_um, mpe_per_mm : float
        MPE = a + L * per_mm (thesis: 0.6 µm + L/600).
    U_a_um, U_b_per_mm : float
        U(L) = sqrt(a² + (b L)²) (thesis appendix 1: 0.52 µm, 1.4e-3).
    uncertainty : callable, optional
        ``U_um(length_mm)`` replacing the formula (e.g. a budget's U(L)).

    Returns
    -------
    MpeResult
    """
    if not isinstance(tables, Mapping) or not tables:
        raise ValueError("tables: expected a non-empty mapping {position: (25, 3) array}.")
    cert = _as_points(certificate, "certificate", n * n)
    pairs = line_pairs(n, diagonals)
    ia = np.array([a - 1 for a, _, _ in pairs])
    ib = np.array([b - 1 for _, b, _ in pairs])
    dirs = np.array([d for _, _, d in pairs])
    L_cert = np.linalg.norm(cert[ib] - cert[ia], axis=1)
    U = (uncertainty(L_cert) if uncertainty is not None
         else uncertainty_um(L_cert, U_a_um, U_b_per_mm))
    U = np.broadcast_to(np.asarray(U, float), L_cert.shape)
    lim = mpe_um(L_cert, mpe_a_um, mpe_per_mm)
    cols: dict[str, list[np.ndarray]] = {k: [] for k in ("position", "a", "b", "d", "L", "e", "U", "m")}
    for name, pts in tables.items():
        pts = _as_points(pts, f"tables[{name!r}]", n * n, missing=True)
        L_meas = np.linalg.norm(pts[ib] - pts[ia], axis=1)
        ok = np.isfinite(L_meas)
        cols["position"].append(np.full(int(ok.sum()), str(name), dtype=object))
        cols["a"].append(ia[ok] + 1)
        cols["b"].append(ib[ok] + 1)
        cols["d"].append(dirs[ok])
        cols["L"].append(L_cert[ok])
        cols["e"].append((L_meas[ok] - L_cert[ok]) * 1e3)
        cols["U"].append(U[ok])
        cols["m"].append(lim[ok])
    cat = {k: np.concatenate(v) for k, v in cols.items()}
    dec = decide(cat["e"], cat["U"], cat["m"])
    counts = {d: int(np.sum(dec == d)) for d in DECISIONS}
    by_pos = {str(name): {d: int(np.sum((dec == d) & (cat["position"] == str(name))))
                          for d in DECISIONS} for name in tables}
    return MpeResult(position=cat["position"].astype(str), ball_a=cat["a"], ball_b=cat["b"],
                     direction=cat["d"], length_mm=cat["L"], error_um=cat["e"],
                     U_um=np.asarray(cat["U"], float), mpe_um=cat["m"], decision=dec,
                     counts=counts, counts_by_position=by_pos)


U_SOURCES = {"test": "the test: plate certificate and repeatability σ",
             "cmm_spec": "the CMM specification U(L) (thesis §6.2)"}
"""Where the U of the conformity decision comes from (see :func:`check_dataset`)."""


def plate_side(certificate: Certificate | None) -> int | None:
    """Balls per side of a square n x n plate's certificate (n >= 3), None for no
    certificate or another ball count: the lengths of :func:`line_pairs` need the grid."""
    if certificate is None:
        return None
    n = math.isqrt(len(certificate.balls))
    return n if n >= 3 and n * n == len(certificate.balls) else None


def check_dataset(dataset: Dataset, *, u_source: str = "test", sigma_um: float = 0.5
                  ) -> tuple[MpeResult | None, list]:
    """MPE check of every position and probe of a dataset against its certificate, a
    square n x n plate (n from 3: the thesis's 5 x 5, a 4 x 4, a 7 x 7), balls row-major.

    ``u_source`` picks U (``U_SOURCES``): ``"test"`` (:func:`conformity_uncertainty_um`
    with ``sigma_um``) or ``"cmm_spec"`` (:func:`uncertainty_um`). Returns ``(result,
    skipped)``: None when there is no certificate of a square plate or no complete table,
    and the position/probe groups left out for missing balls.
    """
    if u_source not in U_SOURCES:
        raise ValueError(f"u_source must be one of {sorted(U_SOURCES)}, got {u_source!r}.")
    cert = dataset.certificate
    n = plate_side(cert)
    if cert is None or n is None:
        return None, []
    tables, skipped = {}, []
    for (pos, prb), _ in dataset.meas.groupby(["position", "probe"], sort=False):
        tab = dataset.plate_frame_table(pos, prb)
        if np.isfinite(tab).all():
            tables[f"{pos}/{prb}"] = tab
        else:
            skipped.append(f"{pos}/{prb}")
    if not tables:
        return None, skipped
    sig = float(sigma_um)
    unc = (lambda L: conformity_uncertainty_um(L, sig)) if u_source == "test" else None
    return mpe_check(tables, cert.xyz_mm, n=n, uncertainty=unc), skipped
