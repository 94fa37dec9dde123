"""Thermal expansion of the machine's scales: an axis whose scale is at T_a reads a length
along it short by α_a (T_a − 20 °C) of the reading (ISO 1), so the true coordinate is the
reading times 1 + α_a ΔT_a. α_a (10⁻⁶/K) is fitted per axis: the scale's expansion
coefficient, or its error when the controller already compensates a nominal one. The
scale temperatures are the ``temp_x_C``, ``temp_y_C``, ``temp_z_C`` columns; an axis
without its column has no parameter.

New points are corrected with the same term at their own scale temperatures
(``compensate``): ``e_a += α_a (T_a − 20 °C) u_a`` for each fitted axis a, u the scale
reading, so the points need the ``temp_a_C`` column of every fitted axis. The model file
keeps the section ``machine_thermal``: the fitted ``axes``, their ``cte_ppm_per_K`` and
``cov_joint``, the joint covariance of the kinematic coefficients, the backlash spans
(when the model has them) and these coefficients.
"""

from __future__ import annotations

from collections.abc import Sequence
from types import MappingProxyType

import numpy as np
import pandas as pd

from ...io import SCALE_TEMP_COLUMNS, TEMP_RANGE_C, DataError
from ...io.delimited import file_rows, numeric_column
from ...io.errors import cut_repr
from ...io.setup import check_celsius
from ...units import PPM, UM
from ..observations import Observations
from .base import Block, Effect
from .compensation import Correction, ModelPart, checked_cov
from .context import Column, Eval, Jacobian, shared_cols
from .simulation import SimCheck, SimContext, SimParam

AXES = "xyz"
SECTION_KEYS = ("axes", "cte_ppm_per_K", "cov_joint")
"""Keys of the model file's ``machine_thermal`` section."""


def _scale_temps(obs):
    """``{axis index: ΔT_K (n,)}`` of the axes whose scale temperature is recorded."""
    out = {}
    for a, col in enumerate(SCALE_TEMP_COLUMNS):
        if col in obs.table and obs.table[col].notna().all():
            out[a] = obs.table[col].to_numpy(float) - 20.0
    return out


class MachineThermal(Block):
    """Expansion coefficient of each recorded axis scale (10⁻⁶/K)."""

    token = "machine_thermal"
    entry = Effect(
        "machine_thermal", "machine scale thermal expansion",
        "an axis's scale is not at 20 °C (or its controller assumes a wrong expansion "
        "coefficient): the axis reads lengths along it short by CTE × (T − 20 °C), a scale "
        "error that changes with the scale's temperature.",
        "temp_x_C, temp_y_C, temp_z_C columns (the scales' temperatures) that vary between "
        "positions or over time.",
        "the linear positioning errors dxx, dyy, dzz when the scale temperature is constant, "
        "and plate thermal expansion when the plate and the scales warm together.",
        "positions measured at different scale temperatures, with the plate temperature "
        "recorded (temp_C).")
    sim_keys = frozenset({f"{a}_cte_per_K" for a in AXES} | {"temp_C"})
    # an error of a compensated coefficient can have either sign
    sim_ranges = MappingProxyType({f"{a}_cte_per_K": (-3e-5, 3e-5) for a in AXES})
    sim_label = "Machine scale expansion"
    sim_help = ("Each scale's expansion error with its temperature (recorded in temp_x_C, "
                "temp_y_C, temp_z_C; 20.5-20.8 °C, warmer at each position).")
    sim_params = tuple(SimParam(f"{a}_cte_per_K", f"{a.upper()} scale CTE error (10⁻⁶/K)",
                                "1e-6/K", 2.0, -30.0, 30.0, 0.5, 1e-6) for a in AXES)
    # plans simulate no scale temperatures: the planner skips it, so no default check
    physical_check = False

    @classmethod
    def injection(cls, values: dict[str, float]) -> dict | None:
        return {f"{lab[-1]}_cte_per_K": v * 1e-6 for lab, v in values.items()}

    @classmethod
    def draw(cls, cfg: dict, sim: SimContext, rng: np.random.Generator) -> dict[str, float]:
        """``x_cte_per_K`` ... (default 0: that scale is not simulated) and each position's
        scale temperatures at its start and finish (``temp_C``: position -> [start,
        finish], shared by the three scales; default 20.5-20.8 °C, 0.5 K warmer at each
        position, the y and z scales 0.2 and 0.4 K warmer than x)."""
        given = cfg.get("temp_C")
        temps = given if isinstance(given, dict) else {}
        out = {}
        for a, axis in enumerate(AXES):
            key = f"{axis}_cte_per_K"
            if key not in cfg:
                continue
            col = {}
            for i, p in enumerate(sim.positions):
                t = temps.get(p)
                col[p] = tuple(t) if t else (20.5 + 0.5 * i + 0.2 * a, 20.8 + 0.5 * i + 0.2 * a)
            sim.columns[SCALE_TEMP_COLUMNS[a]] = col
            out[f"machine_thermal.cte_{axis}"] = float(cfg[key]) * 1e6
        return out

    @staticmethod
    def needs(obs: Observations) -> str | None:
        temps = _scale_temps(obs)
        if not temps:
            return "needs the scales' temperatures (temp_x_C, temp_y_C, temp_z_C columns)"
        if max(np.ptp(t) for t in temps.values()) < 0.01:
            return ("the scale temperatures never change, so the expansion is the linear "
                    "positioning error")
        return None

    def columns(self, obs: Observations) -> list[Column]:
        axes = sorted(_scale_temps(obs))
        return [("machine_thermal", [f"machine_thermal.cte_{AXES[a]}" for a in axes],
                 "1e-6/K")]

    def _terms(self, ev):
        """``(axis, ∂d_axis/∂α_axis (n,))`` per recorded axis: ΔT times the scale
        reading, in µm per 10⁻⁶/K."""
        o = ev.obs
        u = o.r_mm - o.p_mm
        return [(a, dT * u[:, a] * PPM / UM) for a, dT in sorted(_scale_temps(o).items())]

    def reading_stage(self, ev: Eval, d: np.ndarray) -> np.ndarray:
        d = d.copy()
        for alpha, (a, g) in zip(ev.x("machine_thermal"), self._terms(ev), strict=True):
            d[:, a] += alpha * g
        return d

    def jacobian(self, ev: Eval) -> Jacobian:
        terms = self._terms(ev)
        n = len(ev.obs.pos)
        M = np.zeros((n, 3, len(terms)))
        for j, (a, g) in enumerate(terms):
            M[:, a, j] = g
        return [(shared_cols(ev.start("machine_thermal"), len(terms), n), M)]

    @classmethod
    def check_sim(cls, cfg: dict, where: str, check: SimCheck) -> None:
        check.start_finish_C(f"{where}.temp_C", cfg.get("temp_C"))

    # --- compensation of new points -----------------------------------------------------
    model_keys = ("machine_thermal",)
    model_what = "scale expansion coefficients"
    # model files of earlier releases kept only the kinematic coefficients (fitted jointly
    # with the scale term, so they correct as at 20 °C scales): they read as before
    model_keys_optional = True
    comp_units = "1e-6/K"

    @classmethod
    def correction_columns(cls, labels: Sequence[str] | None = None) -> tuple[str, ...]:
        """The scale temperature of every fitted axis (all three when not known)."""
        axes = [AXES.index(lab[-1]) for lab in labels] if labels is not None else range(3)
        return tuple(SCALE_TEMP_COLUMNS[a] for a in axes)

    @classmethod
    def part_to_file(cls, part: ModelPart) -> dict:
        return {"machine_thermal": {"axes": [lab[-1] for lab in part.labels],
                                    "cte_ppm_per_K": part.values.tolist(),
                                    "cov_joint": part.cov.tolist()}}

    @classmethod
    def part_from_file(cls, d: dict, n_before: int, name: str) -> ModelPart | None:
        sec = d.get("machine_thermal")
        if sec is None:
            return None
        col = "machine_thermal"
        if not isinstance(sec, dict) or set(map(str, sec)) != set(SECTION_KEYS):
            raise DataError(f"expected an object with the keys {', '.join(SECTION_KEYS)}, "
                            f"found {cut_repr(sec)}.", file=name, column=col,
                            hint="refit and save the model again (fit --save); do not edit it.")
        axes = sec["axes"]
        if not isinstance(axes, list) or not all(isinstance(a, str) for a in axes) or \
                axes != sorted(set(axes)) or not set(axes) <= set(AXES):
            raise DataError(f"axes must be distinct axes among x, y, z in that order, found "
                            f"{cut_repr(axes)}.", file=name, column=f"{col}.axes")
        try:
            cte = np.asarray(sec["cte_ppm_per_K"], float)
            cov = np.asarray(sec["cov_joint"], float)
        except (TypeError, ValueError) as exc:
            raise DataError(f"expected numbers ({cut_repr(str(exc), 80)}).", file=name,
                            column=col) from None
        k = n_before + len(axes)
        if cte.shape != (len(axes),) or not np.isfinite(cte).all():
            raise DataError(f"expected {len(axes)} finite expansion coefficients "
                            f"(10⁻⁶/K), one per axis, found {cut_repr(sec['cte_ppm_per_K'])}.",
                            file=name, column=f"{col}.cte_ppm_per_K")
        checked_cov(cov, k, name, f"{col}.cov_joint")
        return ModelPart(tuple(f"machine_thermal.cte_{a}" for a in axes), cte, cov)

    @classmethod
    def correct(cls, part: ModelPart, points: pd.DataFrame, x_mm: np.ndarray,
                name: str) -> Correction:
        axes = [AXES.index(lab[-1]) for lab in part.labels]
        need = [SCALE_TEMP_COLUMNS[a] for a in axes]
        missing = [c for c in need if c not in points]
        if missing:
            raise DataError(f"missing column(s) {', '.join(missing)}: the model corrects the "
                            f"thermal expansion of the scales (machine_thermal), so every "
                            f"point needs the temperature of each fitted axis's scale "
                            f"({', '.join(need)}, °C).", file=name, column=missing[0],
                            hint="record the scale temperatures with the points, as in the "
                                 "measurements the model was fitted to.")
        rows = file_rows(points)
        m = len(x_mm)
        delta, jac = np.zeros((m, 3)), np.zeros((m, 3, len(axes)))
        for j, (a, col) in enumerate(zip(axes, need, strict=True)):
            t = numeric_column(points, col, name)
            bad = np.flatnonzero(~np.isfinite(t) | (t < TEMP_RANGE_C[0]) | (t > TEMP_RANGE_C[1]))
            if bad.size:
                check_celsius(t[bad[:1]], name, col, row=int(rows[bad[0]]))
            # the fit's reading stage (eq. in the module docstring), per point
            jac[:, a, j] = (t - 20.0) * x_mm[:, a] * PPM / UM
            delta[:, a] += part.values[j] * jac[:, a, j]
        return Correction(delta, jac)
