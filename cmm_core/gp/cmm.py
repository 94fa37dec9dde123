"""Gaussian-process models of CMM errors: one GP per error component (thesis chapter 5).

Each of the error components e_x, e_y, e_z (µm) of a set of points (machine or plate
coordinates, mm) gets its own GP (``cmm_core.gp.fit_gp``); the fitted processes are
predicted on a grid over a plate's plane or a box of the machine volume as mean and
standard-deviation surfaces (thesis figures 5.4-5.6). The same functions model the
residuals of a kinematic fit, with the kinematic design matrix as the GP's explicit basis
(``basis=``) so that the GP describes only what the kinematic model leaves unexplained.

Where the points were measured with several probes (``probe_mm=``), each GP has the ram
position (tip minus probe offset) and the probe offset as separate inputs, with one
length scale for each: a stylus-dependent error (an angular error seen through the
offset, a probe offset error) is then part of the GP rather than of its noise.

``appendix3_workflow`` reproduces the thesis's appendix 3 script (3×3 plate, zero mean,
then the quadratic mean ``meanMylinear_2D``, prediction on a 21×21 grid, difference of the
two means) in data units, with the source's defects corrected and listed in its docstring.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
from numpy.typing import ArrayLike

from .._blas import single_blas_thread
from .basis import polynomial_basis
from .regression import fit_gp
from .result import GPResult

__all__ = ["GPComponents", "Grid", "gp_components", "predict_grid", "plate_grid", "box_grid",
           "Appendix3Result", "appendix3_workflow"]

COMPONENTS = ("x", "y", "z")


@dataclass(frozen=True, eq=False)
class GPComponents:
    """One fitted GP per error component.

    Attributes
    ----------
    names : tuple of str
        Component names, ``("x", "y", "z")`` (fewer when fewer error columns were given).
    results : tuple of GPResult
        The fitted GP of each component, in the order of ``names``.
    mean : str
        The mean asked for (``"zero"``, ``"quadratic"``, ...; ``"basis"`` when a design
        matrix or callable was given).
    kernel : str
        ``"se_iso"`` or ``"se_ard"``.
    n : int
        Number of points.
    input_dim : int
        Coordinates per point (2 for plate coordinates, 3 for machine coordinates); the GP
        inputs are these plus 3 probe-offset components when ``probe_input``.
    probe_input : bool
        The GPs' inputs are the ram position and the probe offset (several probes), not
        the points alone.
    noise_per_probe : bool
        One noise level per probe (``GPResult.noise_sd_by_group_um``, in the order of
        ``probe_offsets_mm``).
    probe_offsets_mm : ndarray (P, 3) or None
        The distinct probe offsets (mm), sorted, when ``probe_input``.
    """

    names: tuple
    results: tuple
    mean: str
    kernel: str
    n: int
    input_dim: int
    probe_input: bool = False
    noise_per_probe: bool = False
    probe_offsets_mm: np.ndarray | None = None

    def __getitem__(self, name: str) -> GPResult:
        if name not in self.names:
            raise KeyError(f"component {name!r} not fitted: expected one of {self.names}")
        return self.results[self.names.index(name)]

    def summary(self) -> dict:
        """JSON-ready ``{component: {hyperparameters, log_marginal_likelihood,
        loo_rms_um, status, ...}}`` (see ``GPResult.summary``)."""
        return {c: {**r.summary(), "probe_input": self.probe_input}
                for c, r in zip(self.names, self.results, strict=True)}

    def loo_coverage(self, level: float = 0.95) -> dict:
        """Leave-one-out coverage of each component's central ``level`` interval,
        ``{component: fraction}`` (see ``GPResult.loo_coverage``)."""
        return {c: r.loo_coverage(level) for c, r in zip(self.names, self.results, strict=True)}


def _per_component(basis, k, n):
    """Split ``basis`` into one entry per component (None, array, callable or a list)."""
    if basis is None:
        return [None] * k
    if isinstance(basis, list | tuple):
        if len(basis) != k:
            raise ValueError(f"basis is a list of {len(basis)} entries, expected {k} "
                             "(one design matrix per error component)")
        return list(basis)
    return [basis] * k


def _inputs(P, probe_mm):
    """GP inputs (n, d), whether the probe offset is one of them, the index of each point's
    probe among the distinct offsets (None with one probe), and those offsets."""
    if probe_mm is None:
        return P, False, None, None
    Q = np.asarray(probe_mm, dtype=float)
    if Q.ndim == 1:
        Q = np.broadcast_to(Q, P.shape)
    if Q.shape != P.shape or P.shape[1] != 3:
        raise ValueError(f"probe_mm has shape {np.shape(probe_mm)}, expected ({len(P)}, 3): "
                         "the probe offset (mm, machine axes) of each 3-D point")
    uniq, index = np.unique(Q, axis=0, return_inverse=True)
    if len(uniq) < 2:
        return P, False, None, None
    return np.column_stack([P - Q, Q]), True, index.ravel(), uniq


def _groups(kernel, probe_input):
    if not probe_input:
        return None, ()
    return ((0, 0, 0, 1, 1, 1), (1,)) if kernel == "se_iso" else ((0, 1, 2, 3, 3, 3), (3,))


@single_blas_thread
def gp_components(points_mm: ArrayLike, errors_um: ArrayLike, *, mean: str = "zero",
                  kernel: str = "se_iso", basis: ArrayLike | None = None,
                  restarts: int = 3, seed: int = 0, bounds: dict | None = None,
                  probe_mm: ArrayLike | None = None,
                  noise_per_probe: bool = True) -> GPComponents:
    """Fit one GP per error component.

    Parameters
    ----------
    points_mm : array_like (n, 3) or (n, 2)
        Machine or plate coordinates of the points, mm.
    errors_um : array_like (n, 3) (or (n, k), k <= 3)
        Error (or kinematic-fit residual) components at the points, µm.
    mean : str
        Built-in mean (``cmm_core.gp.MEANS``): ``"zero"`` (thesis appendix 3 T2),
        ``"quadratic"`` (full quadratic), ``"thesis_quadratic"`` (eq. 5.11), ...
    kernel : {"se_iso", "se_ard"}
    basis : array_like (n, m), callable, or list of k of these, optional
        Explicit basis (e.g. the kinematic model's per-component design matrix from
        ``cmm_core.diagnosis.kinematic_basis``), marginalised analytically (R&W §2.7). Use
        either this or a non-zero ``mean``.
    restarts : int
        Random restarts of the hyperparameter optimisation per component.
    seed : int
        Seed of ``np.random.default_rng``; component c uses ``seed + c``.
    bounds : dict, optional
        Hyperparameter bounds in mm / µm (see ``fit_gp``).
    probe_mm : array_like (n, 3) or (3,), optional
        Probe offset of each point (mm, machine axes), with ``points_mm`` the tip centres.
        With two or more different offsets the inputs are the ram position
        ``points_mm - probe_mm`` (one length scale, or one per axis for ``se_ard``) and the
        offset (one length scale of its own; at either bound it means independent or
        irrelevant probes, not a degenerate fit); a polynomial mean is then a polynomial
        of the ram position. With one offset, or None, the inputs are ``points_mm``.
    noise_per_probe : bool
        With the probe offset as input, one noise level per probe (styli differ in
        repeatability; on the thesis data one placement, BP112, is much noisier than
        the others and a common noise level leaves its points outside their intervals).

    Returns
    -------
    GPComponents
    """
    P = np.asarray(points_mm, dtype=float)
    E = np.asarray(errors_um, dtype=float)
    if P.ndim != 2 or P.shape[1] not in (2, 3):
        raise ValueError(f"points_mm has shape {P.shape}, expected (n, 3) machine or (n, 2) "
                         "plate coordinates in mm")
    if E.ndim == 1:
        E = E[:, None]
    if E.ndim != 2 or E.shape[0] != P.shape[0] or not 1 <= E.shape[1] <= 3:
        raise ValueError(f"errors_um has shape {np.shape(errors_um)}, expected "
                         f"({P.shape[0]}, 3): one row of error components (µm) per point")
    if basis is not None and mean not in ("zero", None):
        raise ValueError(f"both mean={mean!r} and a basis were given: expected one of them "
                         "(append the polynomial columns to the basis to combine them)")
    k = E.shape[1]
    bases = _per_component(basis, k, P.shape[0])
    X, probe_input, probe_index, offsets = _inputs(P, probe_mm)
    groups, discrete = _groups(kernel, probe_input)
    noise_groups = probe_index if noise_per_probe else None
    results = []
    for c in range(k):
        mc = bases[c] if bases[c] is not None else (mean or "zero")
        if probe_input and isinstance(mc, str) and mc != "zero":
            mc = _ram_polynomial(mc)
        results.append(fit_gp(X, E[:, c], mean=mc, kernel=kernel, restarts=restarts,
                              seed=int(seed) + c, bounds=bounds, groups=groups,
                              discrete_groups=discrete, noise_groups=noise_groups))
    return GPComponents(names=COMPONENTS[:k], results=tuple(results),
                        mean="basis" if basis is not None else (mean or "zero"),
                        kernel=kernel, n=P.shape[0], input_dim=P.shape[1],
                        probe_input=probe_input,
                        noise_per_probe=noise_groups is not None, probe_offsets_mm=offsets)


def _ram_polynomial(kind):
    """A built-in polynomial mean of the ram position (the first three inputs)."""
    polynomial_basis(np.zeros((1, 3)), kind)  # unknown names raise here, with the hint

    def h(X):
        return polynomial_basis(np.asarray(X)[:, :3], kind)[0]
    return h


@single_blas_thread
def predict_grid(components: GPComponents, grid_points_mm: ArrayLike, *,
                 basis_grid: ArrayLike | None = None,
                 probe_mm: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation of each component's GP at grid points.

    Parameters
    ----------
    components : GPComponents
    grid_points_mm : array_like (m, d)
        Points in the same coordinates as the training points (e.g. ``Grid.points_mm``).
    basis_grid : array_like (m, p) or list of them, optional
        The explicit basis at the grid points, when the GPs were fitted with a design
        matrix. Without it such components give the GP part alone (the discrepancy from the
        parametric model, conditional on its fitted coefficients): see ``GPResult.predict``.
    probe_mm : array_like (3,) or (m, 3), optional
        The probe offset the prediction is for (mm), required when the GPs have the probe
        offset as input (``components.probe_input``): the error of the tip at
        ``grid_points_mm`` measured with that stylus.

    Returns
    -------
    mean_um : ndarray (m, k)
    sd_um : ndarray (m, k)
        Standard deviation of the latent error (noise excluded).
    """
    G = np.asarray(grid_points_mm, dtype=float)
    if G.ndim != 2 or G.shape[1] != components.input_dim:
        raise ValueError(f"grid_points_mm has shape {G.shape}, expected (m, "
                         f"{components.input_dim}) like the points the GPs were fitted on")
    if components.probe_input:
        if probe_mm is None:
            raise ValueError("these GPs have the probe offset as input: pass probe_mm, the "
                             "stylus offset (mm) to predict for")
        Q = np.broadcast_to(np.asarray(probe_mm, dtype=float), G.shape)
        G = np.column_stack([G - Q, Q])
    k = len(components.results)
    hb = _per_component(basis_grid, k, len(G))
    mean = np.empty((len(G), k))
    sd = np.empty((len(G), k))
    for c, r in enumerate(components.results):
        needs_h = r.mean == "matrix"
        mu, var = r.predict(G, H_new=hb[c], include_mean=not needs_h or hb[c] is not None)
        mean[:, c], sd[:, c] = mu, np.sqrt(var)
    return mean, sd


@dataclass(frozen=True, eq=False)
class Grid:
    """A regular grid of points for drawing surfaces.

    Attributes
    ----------
    axes_mm : tuple of ndarray
        The grid coordinates along each grid axis (``u``, ``v`` for a plate; x, y, z for a box).
    points_mm : ndarray (m, d)
        The grid points, the first axis varying fastest (thesis appendix 3 ordering).
    shape : tuple of int
        Shape for ``surface``: ``(n_v, n_u)`` for a plate, ``(n_z, n_y, n_x)`` for a box.
    """

    axes_mm: tuple
    points_mm: np.ndarray
    shape: tuple

    def surface(self, values: ArrayLike) -> np.ndarray:
        """Reshape per-point values (m,) to the grid's shape (rows = second axis)."""
        return np.asarray(values).reshape(self.shape)


def _axis(rng, n, name):
    lo, hi = (float(t) for t in rng)
    if not (np.isfinite(lo) and np.isfinite(hi) and hi >= lo):
        raise ValueError(f"{name} = {rng}: expected (low, high) with low <= high, in mm")
    return np.linspace(lo, hi, int(n))


def plate_grid(u_range_mm: tuple[float, float], v_range_mm: tuple[float, float],
               n: int | tuple[int, int] = 21, *, origin_mm: np.ndarray | None = None,
               u_axis: np.ndarray | None = None, v_axis: np.ndarray | None = None) -> Grid:
    """Grid over a plate's plane.

    Without ``origin_mm`` the points are plate coordinates ``(u, v)`` (n², 2); with it they
    are machine coordinates ``origin + u*u_axis + v*v_axis`` (n², 3), as a setup placement.
    ``n`` may be an int or ``(n_u, n_v)``. The thesis grid is ``plate_grid((400, 600),
    (400, 600), 21)`` (appendix 3, step 10 mm).
    """
    nu, nv = cast("tuple[int, int]", (n, n) if np.ndim(n) == 0 else n)
    if min(nu, nv) < 2:
        raise ValueError(f"n = {n}: expected at least 2 points per axis")
    u = _axis(u_range_mm, nu, "u_range_mm")
    v = _axis(v_range_mm, nv, "v_range_mm")
    U, V = np.meshgrid(u, v)
    pts = np.column_stack([U.ravel(), V.ravel()])
    if origin_mm is not None:
        o = np.asarray(origin_mm, dtype=float)
        a = np.asarray(u_axis if u_axis is not None else (1, 0, 0), dtype=float)
        b = np.asarray(v_axis if v_axis is not None else (0, 1, 0), dtype=float)
        if o.shape != (3,) or a.shape != (3,) or b.shape != (3,):
            raise ValueError("origin_mm, u_axis and v_axis must be 3-vectors (machine axes)")
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        pts = o + pts[:, :1] * a + pts[:, 1:] * b
    return Grid(axes_mm=(u, v), points_mm=pts, shape=(nv, nu))


def box_grid(lower_mm: ArrayLike, upper_mm: ArrayLike,
             n: int | tuple[int, int, int] = 11) -> Grid:
    """Grid over a box of the machine volume (n per axis or (n_x, n_y, n_z)), x fastest."""
    lo = np.asarray(lower_mm, dtype=float)
    hi = np.asarray(upper_mm, dtype=float)
    if lo.shape != (3,) or hi.shape != (3,):
        raise ValueError("lower_mm and upper_mm must be 3-vectors (x, y, z) in mm")
    ns = (n, n, n) if np.ndim(n) == 0 else tuple(cast(tuple, n))
    axes = tuple(_axis((lo[i], hi[i]), ns[i], f"axis {'xyz'[i]}") for i in range(3))
    Z, Y, X = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    pts = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    return Grid(axes_mm=axes, points_mm=pts, shape=(ns[2], ns[1], ns[0]))


# --------------------------------------------------------------------------- appendix 3

@dataclass(frozen=True, eq=False)
class Appendix3Result:
    """The thesis appendix 3 workflow's results, ready for figures 5.4-5.6.

    Attributes
    ----------
    points_mm : ndarray (9, 2)
        The 3×3 plate's ball positions (mm).
    errors_um : ndarray (9, k)
        The errors fitted (µm).
    grid : Grid
        The 21×21 prediction grid over 400..600 mm (step 10 mm).
    zero, quadratic : GPComponents
        GPs with zero mean (part T2) and with the quadratic mean (part T3, eq. 5.11).
    mean_zero_um, sd_zero_um, mean_quadratic_um, sd_quadratic_um : ndarray (21, 21, k)
        Mean and standard deviation surfaces (figures 5.4 and 5.5 show the means).
    difference_um : ndarray (21, 21, k)
        |mean_zero - mean_quadratic| (figure 5.6, which the thesis labels "errors": it is
        the difference between the two models, not an error of either).
    """

    points_mm: np.ndarray
    errors_um: np.ndarray
    grid: Grid
    zero: GPComponents
    quadratic: GPComponents
    mean_zero_um: np.ndarray
    sd_zero_um: np.ndarray
    mean_quadratic_um: np.ndarray
    sd_quadratic_um: np.ndarray
    difference_um: np.ndarray


def appendix3_workflow(errors_um: ArrayLike | None = None, *, noise_sd_um: float = 0.3, seed: int = 0,
                       kernel: str = "se_iso", restarts: int = 3, n_grid: int = 21,
                       quadratic_mean: str = "thesis_quadratic") -> Appendix3Result:
    """Thesis appendix 3 (figures 5.2-5.6) done in data units.

    A 3×3 plate at 400, 500, 600 mm; errors at the balls (given, or simulated: a scale
    error of 10 µm/m about the plate centre, a 0.5 µm/100 mm² quadratic bow and seeded
    Gaussian noise of ``noise_sd_um``); a GP with zero mean, then one with the quadratic
    mean of eq. 5.11 (``meanMylinear_2D``), both predicted on the 21×21 grid.

    Corrections of the source: the script's "errors" are pure random noise and the same
    noise is also added to the inputs (``XT = X + adjnoise``), with metres and millimetres
    mixed; its mean coefficients are optimised as hyperparameters from hand-set starting
    values, whereas here they are marginalised (R&W §2.7) and the covariance is fitted by
    maximum marginal likelihood with restarts.
    """
    g = np.array([400.0, 500.0, 600.0])
    U, V = np.meshgrid(g, g)
    pts = np.column_stack([U.ravel(), V.ravel()])
    if errors_um is None:
        rng = np.random.default_rng(seed)
        du, dv = (pts[:, 0] - 500) / 100, (pts[:, 1] - 500) / 100
        errors_um = np.column_stack([
            1.0 * du + 0.5 * du**2, 1.0 * dv + 0.5 * du * dv, 0.5 * du**2 + 0.3 * dv**2,
        ]) + noise_sd_um * rng.standard_normal((9, 3))
    E = np.asarray(errors_um, dtype=float)
    if E.ndim == 1:
        E = E[:, None]
    if E.shape[0] != 9:
        raise ValueError(f"errors_um has {E.shape[0]} rows, expected 9 (one per ball of the "
                         "3×3 plate, row by row from (400, 400) mm)")
    grid = plate_grid((400, 600), (400, 600), n_grid)
    zero = gp_components(pts, E, mean="zero", kernel=kernel, restarts=restarts, seed=seed)
    quad = gp_components(pts, E, mean=quadratic_mean, kernel=kernel, restarts=restarts,
                         seed=seed)
    m0, s0 = predict_grid(zero, grid.points_mm)
    mq, sq = predict_grid(quad, grid.points_mm)
    shape = (*grid.shape, E.shape[1])
    return Appendix3Result(points_mm=pts, errors_um=E, grid=grid, zero=zero, quadratic=quad,
                           mean_zero_um=m0.reshape(shape), sd_zero_um=s0.reshape(shape),
                           mean_quadratic_um=mq.reshape(shape),
                           sd_quadratic_um=sq.reshape(shape),
                           difference_um=np.abs(m0 - mq).reshape(shape))
