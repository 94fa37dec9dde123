"""Figures (Plotly) shared by the app and the HTML report, so both show the same thing.

Micrometres on screen, units on every axis. The report itself
(``cmm_core.analysis.report``) draws with these builders.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import plotly.express as px
import plotly.graph_objects as go
from numpy.typing import ArrayLike
from plotly.subplots import make_subplots

from ..gum import LengthDependence, MpeResult
from ..io import Dataset
from ..machine import SQUARENESS, STRAIGHTNESS, axis_of, basis, periodic_basis, rigid_fit
from ..model import FitResult
from ..units import UM
from ..units import label as unit_label

AXIS_COLOURS = {"x": "#1f77b4", "y": "#2ca02c", "z": "#d62728"}
FUNCTION_UNITS = {"d": "µm", "r": "µrad", "s": "µrad"}


def _layout(fig, title, height=None):
    fig.update_layout(title=title, margin={"l": 60, "r": 20, "t": 60, "b": 50},
                      legend={"orientation": "h", "y": -0.15}, template="plotly_white")
    if height:
        fig.update_layout(height=height)
    return fig


# ---------------------------------------------------------------------------------------
# Error functions
# ---------------------------------------------------------------------------------------

def error_function_curves(result: FitResult, name: str, n: int = 61
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(u_mm, value, u95)`` of one fitted error function along its axis, with the 95 %
    band half-width (k = 2). Units: µm for d.., µrad for r.. and s.. (squareness angle)."""
    terms = result.terms
    axis = axis_of(name)
    stroke = float(terms.range_mm[axis])
    u = np.linspace(0.0, stroke, n)
    sl = terms.slices.get(name)
    if sl is None or sl.stop == sl.start:
        return u, np.zeros(n), np.zeros(n)
    coef = result.kinematic_coef[sl]
    V = result.kinematic_cov[sl, sl]
    if name in SQUARENESS:  # the coefficient is the angle itself (µrad)
        val = np.full(n, float(coef[0]))
        sd = np.full(n, float(np.sqrt(max(V[0, 0], 0.0))))
    else:
        D = terms.design(name, u)
        val = D @ coef
        sd = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", D, V, D), 0, None))
    if name in set(result.unidentifiable) or any(
            lab.startswith(name + "[") or lab == name for lab in result.unidentifiable):
        sd = np.full(n, np.nan)
    return u, val, 2.0 * sd


def true_function_curve(truth: dict, name: str, u_mm: np.ndarray, range_mm: ArrayLike
                        ) -> np.ndarray | None:
    """A simulation's true error function along its axis (µm or µrad), from the truth's
    coefficient labels (``dyz[3]``, ``dxx[sin180]``); None when the truth has none."""
    if name in SQUARENESS:
        return None if name not in truth else np.full(len(u_mm), float(truth[name]))
    poly: dict[int, float] = {}
    per: dict[float, dict[str, float]] = {}
    for lab, v in truth.items():
        base, _, rest = lab.partition("[")
        if base != name or not rest.endswith("]"):
            continue
        k = rest[:-1]
        if k.isdigit():
            poly[int(k)] = float(v)
        elif k[:3] in ("sin", "cos"):
            per.setdefault(float(k[3:]), {})[k[:3]] = float(v)
    if not poly and not per:
        return None
    stroke = float(np.asarray(range_mm, float)[axis_of(name)])
    val = np.zeros(len(u_mm))
    if poly:
        order = max(poly)
        first = 2 if name in STRAIGHTNESS else 1
        coef = np.array([poly.get(j, 0.0) for j in range(first, order + 1)])
        val += basis(name, np.asarray(u_mm, float), order, stroke) @ coef
    for period, sc in per.items():
        val += periodic_basis(np.asarray(u_mm, float), period) @ np.array(
            [sc.get("sin", 0.0), sc.get("cos", 0.0)])
    return val


def fig_error_functions(result: FitResult, names: list | tuple | None = None, cols: int = 3,
                        truth: dict | None = None) -> go.Figure:
    """Fitted error functions with 95 % bands (k = 2), one panel per function; the span of
    the measured scale readings shaded, and a simulation's true functions dashed when
    ``truth`` (label -> value) is given."""
    present = [n for n, _ in result.terms.functions]
    names = [n for n in (names or present) if n in present]
    if not names:
        fig = go.Figure()
        return _layout(fig, "No kinematic error functions in the model")
    rows = int(np.ceil(len(names) / cols))
    fig = make_subplots(rows=rows, cols=cols, subplot_titles=names,
                        vertical_spacing=min(0.08, 0.6 / max(rows, 1)))
    traces, trows, tcols, axes, spans = [], [], [], {}, []
    for i, name in enumerate(names):
        r, c = i // cols + 1, i % cols + 1
        u, val, band = error_function_curves(result, name)
        colour = AXIS_COLOURS["xyz"[axis_of(name)]]
        if np.isfinite(band).all():
            traces.append(go.Scatter(x=np.r_[u, u[::-1]], y=np.r_[val + band, (val - band)[::-1]],
                                     fill="toself", fillcolor="rgba(120,120,120,0.25)",
                                     line={"width": 0}, hoverinfo="skip", showlegend=i == 0,
                                     name="95 % band (k = 2)"))
            trows.append(r)
            tcols.append(c)
        traces.append(go.Scatter(x=u, y=val, mode="lines", line={"color": colour},
                                 name=name, showlegend=False,
                                 hovertemplate=f"{name}: %{{y:.3f}}<extra></extra>"))
        trows.append(r)
        tcols.append(c)
        true = None if truth is None else true_function_curve(truth, name, u,
                                                              result.terms.range_mm)
        if true is not None:
            traces.append(go.Scatter(x=u, y=true, mode="lines", name="true (simulation)",
                                     line={"color": "#222", "dash": "dash", "width": 1},
                                     showlegend=not any(t.name == "true (simulation)"
                                                        for t in traces),
                                     hovertemplate=f"true {name}: %{{y:.3f}}<extra></extra>"))
            trows.append(r)
            tcols.append(c)
        ax = axis_of(name)
        x_meas = result.problem.obs.r_mm[:, ax] - result.problem.obs.p_mm[:, ax]
        n = "" if i == 0 else str(i + 1)
        # the measured span as one layout shape per panel, all set at once: add_vrect
        # validates the whole layout per call (1 s for 21 panels)
        spans.append({"type": "rect", "xref": f"x{n}", "yref": f"y{n} domain",
                      "x0": float(x_meas.min()), "x1": float(x_meas.max()), "y0": 0, "y1": 1,
                      "fillcolor": "rgba(31,119,180,0.07)", "line": {"width": 0},
                      "layer": "below"})
        axes[f"xaxis{n}"] = {"title": {"text": f"{'xyz'[axis_of(name)]} (mm)"}}
        axes[f"yaxis{n}"] = {"title": {"text": FUNCTION_UNITS[name[0]]}}
    fig.add_traces(traces, rows=trows, cols=tcols)
    fig.update_layout(axes, shapes=spans)
    return _layout(fig, "Fitted error functions with 95 % bands", height=260 * rows)


# ---------------------------------------------------------------------------------------
# Magnified deviation plots (thesis figures 4.8-4.10)
# ---------------------------------------------------------------------------------------

def deviations_plate_frame(result: FitResult, position: str, probe: str | None = None
                           ) -> pd.DataFrame:
    """Measured and model-predicted deviations from the (fitted) plate, plate frame, µm.

    The fitted placement of the position maps the reported points back to the plate frame;
    the model-predicted reported point is ``r - residual``. The rigid motion that best aligns
    the measured points with the nominal ones is removed from both (only the shape shows).
    """
    obs = result.problem.obs
    st = result.state
    t = result.table
    sel = (t["position"] == position).to_numpy()
    if probe is not None:
        sel &= (t["probe"].astype(str) == str(probe)).to_numpy()
    if not sel.any():
        return pd.DataFrame()
    k = obs.positions.index(position)
    R, tr, plate = st.R[k], st.t[k], st.c
    r = obs.r_mm[sel]
    d = result.residuals_um[sel]
    c = plate[obs.ball[sel]]
    meas = (r - tr) @ R - c
    pred = (r - d * UM - tr) @ R - c
    # Show the shape, not where the plate sits: remove the rigid motion that best aligns the
    # measured points with the nominal ones (the same motion is applied to the prediction).
    if len(c) >= 3:
        R2, t2 = rigid_fit(c + meas, c)
        meas = (c + meas) @ R2.T + t2 - c
        pred = (c + pred) @ R2.T + t2 - c
    out = pd.DataFrame({"ball": t["ball"].to_numpy()[sel], "probe": t["probe"].to_numpy()[sel],
                        "u_mm": c[:, 0], "v_mm": c[:, 1], "w_mm": c[:, 2]})
    for i, a in enumerate("uvw"):
        out[f"meas_d{a}_um"] = meas[:, i] / UM
        out[f"pred_d{a}_um"] = pred[:, i] / UM
    return out


def fig_deviation(result: FitResult, position: str, magnification: float = 2000.0,
                  probe: str | None = None) -> go.Figure:
    """Nominal grid, measured and predicted points with deviations magnified (plate frame)."""
    df = deviations_plate_frame(result, position, probe)
    fig = go.Figure()
    if df.empty:
        return _layout(fig, f"{position}: no observations")
    m = magnification * UM  # µm -> mm, magnified
    u, v = df["u_mm"].to_numpy(), df["v_mm"].to_numpy()
    fig.add_trace(go.Scatter(x=u, y=v, mode="markers", name="nominal (certificate)",
                             marker={"symbol": "circle-open", "size": 9, "color": "black"},
                             text=df["ball"], hovertemplate="ball %{text}<extra>nominal</extra>"))
    for kind, colour, sym in (("meas", "#d62728", "x"), ("pred", "#1f77b4", "cross")):
        x = u + m * df[f"{kind}_du_um"].to_numpy()
        y = v + m * df[f"{kind}_dv_um"].to_numpy()
        label = "measured" if kind == "meas" else "predicted by model"
        fig.add_trace(go.Scatter(
            x=x, y=y, mode="markers", name=label,
            marker={"symbol": sym, "size": 8, "color": colour},
            customdata=np.column_stack([df["ball"], df[f"{kind}_du_um"], df[f"{kind}_dv_um"],
                                        df[f"{kind}_dw_um"]]),
            hovertemplate=("ball %{customdata[0]}<br>du %{customdata[1]:.2f} µm<br>"
                           "dv %{customdata[2]:.2f} µm<br>dw %{customdata[3]:.2f} µm"
                           f"<extra>{label}</extra>")))
        # lines from nominal to the magnified point
        xs = np.column_stack([u, x, np.full_like(u, np.nan)]).ravel()
        ys = np.column_stack([v, y, np.full_like(v, np.nan)]).ravel()
        fig.add_trace(go.Scatter(x=xs, y=ys, mode="lines", showlegend=False,
                                 line={"color": colour, "width": 1}, hoverinfo="skip"))
    # scale key: a bar about a tenth of the plate long, labelled with the deviation it means
    span = float(max(np.ptp(u), np.ptp(v), 1.0))
    raw = 0.1 * span / m
    bar_um = float(min((k * 10 ** e for e in range(-2, 4) for k in (1, 2, 5)),
                       key=lambda b: abs(np.log(b / raw))))
    y_bar = float(v.min()) - 0.08 * span
    fig.add_trace(go.Scatter(x=[u.min(), u.min() + bar_um * m], y=[y_bar, y_bar],
                             mode="lines+text", line={"color": "black", "width": 3},
                             text=["", f"{bar_um:g} µm"], textposition="middle right",
                             name=f"scale: {bar_um:g} µm deviation", hoverinfo="skip"))
    fig.update_xaxes(title_text=f"plate u (mm); deviations ×{magnification:g}",
                     constrain="domain")
    fig.update_yaxes(title_text=f"plate v (mm); deviations ×{magnification:g}",
                     scaleanchor="x", scaleratio=1)
    return _layout(fig, f"{position}: nominal vs measured vs predicted "
                        f"(magnification ×{magnification:g})", height=600)


# ---------------------------------------------------------------------------------------
# Residual patterns, signatures, maps
# ---------------------------------------------------------------------------------------

def fig_pattern(table: pd.DataFrame, values_um: ArrayLike, title: str,
                height: int = 330) -> go.Figure:
    """A per-observation pattern (residuals or a candidate's signature), µm, three panels
    (x, y, z) over the observations grouped by position."""
    values_um = np.asarray(values_um, float)
    labels = (table["position"].astype(str) + "/" + table["probe"].astype(str) + " b"
              + table["ball"].astype(str)).to_numpy()
    idx = np.arange(len(table))
    fig = make_subplots(rows=1, cols=3, subplot_titles=("x", "y", "z"), shared_yaxes=True)
    positions = list(dict.fromkeys(table["position"]))
    palette = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b",
               "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"]
    traces, tcols = [], []
    for j, pos in enumerate(positions):
        sel = (table["position"] == pos).to_numpy()
        for a in range(3):
            traces.append(go.Scatter(x=idx[sel], y=values_um[sel, a], mode="markers",
                                     marker={"size": 5, "color": palette[j % len(palette)]},
                                     name=str(pos), legendgroup=str(pos), showlegend=a == 0,
                                     text=labels[sel],
                                     hovertemplate="%{text}: %{y:.3f} µm<extra></extra>"))
            tcols.append(a + 1)
    fig.add_traces(traces, rows=[1] * len(traces), cols=tcols)
    # one axis title under the middle panel: three would overlap in a half-width column
    fig.update_xaxes(title_text="observation (grouped by position)", row=1, col=2)
    fig.update_yaxes(title_text="µm", row=1, col=1)
    _layout(fig, title, height=height)
    fig.update_layout(legend={"orientation": "h", "y": -0.32, "x": 0},
                      margin={"t": 60, "b": 90})
    return fig


def fig_residual_map(result: FitResult, component: str = "norm") -> go.Figure:
    """Residuals at the measured points in the machine volume (colour in µm)."""
    t = result.table
    d = result.residuals_um
    val = np.linalg.norm(d, axis=1) if component == "norm" else d[:, "xyz".index(component)]
    label = "|residual|" if component == "norm" else f"residual {component}"
    fig = go.Figure(go.Scatter3d(
        x=t["mx_mm"], y=t["my_mm"], z=t["mz_mm"], mode="markers",
        marker={"size": 4, "color": val, "colorscale": "RdBu_r" if component != "norm"
                else "Viridis", "colorbar": {"title": {"text": f"{label} (µm)"}}},
        text=t["position"].astype(str) + " ball " + t["ball"].astype(str),
        hovertemplate="%{text}<br>%{marker.color:.3f} µm<extra></extra>"))
    fig.update_layout(scene={"xaxis_title": "X (mm)", "yaxis_title": "Y (mm)",
                             "zaxis_title": "Z (mm)", "aspectmode": "data"})
    return _layout(fig, f"Residual map: {label} in µm", height=480)


def fig_signature_scatter(residuals_um: ArrayLike, signature_um: ArrayLike, title: str,
                          height: int = 300) -> go.Figure:
    """Residual against a candidate's signature, per component, with the 1:1 line: an
    effect that explains the misfit puts the points along the line (their scatter about it
    is the noise); one that does not leaves a cloud around zero."""
    r = np.asarray(residuals_um, float)
    sg = np.asarray(signature_um, float)
    fig = make_subplots(rows=1, cols=3, subplot_titles=("x", "y", "z"), shared_yaxes=True)
    lim = float(np.nanmax(np.abs(sg))) or 1.0
    for a in range(3):
        fig.add_trace(go.Scatter(x=sg[:, a], y=r[:, a], mode="markers", showlegend=False,
                                 marker={"size": 4, "opacity": 0.6},
                                 hovertemplate="signature %{x:.3f} µm<br>residual %{y:.3f} "
                                               "µm<extra></extra>"), row=1, col=a + 1)
        fig.add_trace(go.Scatter(x=[-lim, lim], y=[-lim, lim], mode="lines", showlegend=False,
                                 line={"color": "#888", "dash": "dash"}, hoverinfo="skip"),
                      row=1, col=a + 1)
    fig.update_xaxes(title_text="signature (µm)", row=1, col=2)
    fig.update_yaxes(title_text="residual (µm)", row=1, col=1)
    return _layout(fig, title, height=height)


EN_CLASSES = ((2.0, "#2ca02c"), (3.0, "#ff7f0e"), (np.inf, "#d62728"))
"""The |E_n| classes of an interim check's map: (upper limit of the standard score
``|residual / u|``, colour). At a coverage factor k the limits are ``2 / k`` and
``3 / k`` of E_n (ISO/IEC 17043:2010 Annex B, ``E_n = residual / (k u)``): at k = 2,
``|E_n| <= 1`` (the usual acceptance: each of x, y, z within its expanded uncertainty),
``1 < |E_n| <= 1.5`` and ``|E_n| > 1.5``. The class takes the largest of a ball's three
components (on an unchanged machine some 0.954³ = 87 % of balls are in the first)."""


def en_classes(coverage_factor: float = 2.0) -> list:
    """:data:`EN_CLASSES` at a coverage factor: ``(upper limit of |E_n|, legend label,
    colour)`` each, the labels stating k (``"|E_n| ≤ 1 (k = 2)"``)."""
    k = float(coverage_factor)
    lims = [z / k for z, _ in EN_CLASSES]
    tag = f" (k = {k:g})"
    labels = [f"|E_n| ≤ {lims[0]:.3g}{tag}",
              f"{lims[0]:.3g} < |E_n| ≤ {lims[1]:.3g}{tag}",
              f"|E_n| > {lims[1]:.3g}{tag}"]
    return [(lim, lab, col) for lim, lab, (_, col) in zip(lims, labels, EN_CLASSES,
                                                           strict=True)]


EN_PLACE_MM = 1.0
"""An E_n map's place: the observations whose x and y (mm) round to one cell of this
size are one marker (styli probing one ball, balls of a vertical plate at one x, y)."""


def _en_places(table: pd.DataFrame, k: float) -> pd.DataFrame:
    """One row per place of :func:`fig_en_map`: its x, y (mm), the largest ``|E_n|`` of
    its observations (NaN when none has one) and a hover text listing them."""
    xy_mm = table[["x_mm", "y_mm"]].to_numpy(float)
    table = table[np.isfinite(xy_mm).all(axis=1)]  # a place without x, y is not drawn
    xy = np.round(table[["x_mm", "y_mm"]].to_numpy(float) / EN_PLACE_MM)
    key = pd.Series([f"{a:.0f},{b:.0f}" for a, b in xy], index=table.index)
    rows = []
    for _, g in table.groupby(key, sort=False):
        en = np.abs(g["En"].to_numpy(float))
        lines = [f"{r.position} stylus {r.probe} ball {r.ball}: E_n x {_en_text(r.En_x)}, "
                 f"y {_en_text(r.En_y)}, z {_en_text(r.En_z)}" for r in g.itertuples()]
        x0, y0 = (round(float(g[c].iloc[0])) for c in ("x_mm", "y_mm"))  # an int: no "-0"
        head = (f"x {x0}, y {y0} mm, "
                f"{len(g)} observation{'s' if len(g) > 1 else ''} (k = {k:g})")
        rows.append({"x_mm": float(g["x_mm"].mean()), "y_mm": float(g["y_mm"].mean()),
                     "En": float(np.nanmax(en)) if np.isfinite(en).any() else np.nan,
                     "hover": "<br>".join([head, *lines])})
    return pd.DataFrame(rows, columns=["x_mm", "y_mm", "En", "hover"])


def _en_text(v: float) -> str:
    """An E_n component for a hover: "not computed" rather than "nan"."""
    return f"{v:+.2f}" if np.isfinite(v) else "not computed"


def fig_en_map(table: pd.DataFrame, title: str, height: int = 420, *,
               coverage_factor: float = 2.0) -> go.Figure:
    """The normalised errors of an interim check's new observations over the machine's
    x, y (mm): one marker per place (observations within :data:`EN_PLACE_MM` of each other:
    styli on one ball, balls of a vertical plate above each other), coloured by the
    :func:`en_classes` class of the largest ``|E_n|`` of x, y, z over the observations
    there (grey where no E_n could be computed); each legend entry counts its places, so
    the counts are the markers drawn. The hover title lists every observation of the place
    with its three components.

    ``table`` is ``monitor`` ``InterimCheck.table`` (columns ``x_mm, y_mm, position,
    probe, ball, En_x, En_y, En_z, En``, E_n at ``coverage_factor``, the check's
    ``InterimCheck.coverage_factor``).
    """
    k = float(coverage_factor)
    places = _en_places(table, k)
    en = places["En"].to_numpy(float)
    lower = -np.inf
    fig = go.Figure()
    classes = [*en_classes(k), (np.nan, "E_n not computed", "#999999")]
    for upper, name, colour in classes:
        sub = places[np.isnan(en)] if np.isnan(upper) else places[(en > lower) & (en <= upper)]
        if np.isnan(upper) and not len(sub):
            continue  # no place without E_n: no legend entry for it
        lower = upper
        fig.add_trace(go.Scatter(
            x=sub["x_mm"], y=sub["y_mm"], mode="markers", name=f"{name}: {len(sub)}",
            marker={"color": colour, "size": 9}, text=sub["hover"],
            hovertemplate="%{text}<extra></extra>"))
    fig.update_xaxes(title_text="x (mm)")
    fig.update_yaxes(title_text="y (mm)", scaleanchor="x")
    return _layout(fig, title, height=height)


def fig_budget_vs_length(ld: LengthDependence, title: str | None = None) -> go.Figure:
    """The ball-plate budget's expanded uncertainty U(L) (µm, k from ν_eff) over the
    plate's lengths (``gum.budget_vs_length``), beside the CMM's and the plate
    certificate's specifications (thesis section 6.3)."""
    fig = go.Figure()
    fig.add_scatter(x=ld.length_mm, y=ld.U_um, mode="markers+lines", name="budget U(L)")
    fig.add_scatter(x=ld.length_mm, y=ld.cmm_spec_U_um, mode="lines",
                    name="CMM specification √(0.52² + (1.4e-3 L)²)")
    fig.add_scatter(x=ld.length_mm, y=ld.plate_spec_U_um, mode="lines",
                    name="plate certificate √(0.26² + (1.9e-3 L)²)")
    fig.update_layout(xaxis_title="L (mm)", yaxis_title="U (µm, k from ν_eff)",
                      legend={"orientation": "h", "y": -0.25})
    return _layout(fig, title, height=360)


def fig_residuals_time(residuals: pd.DataFrame) -> go.Figure:
    """Residuals (µm) against the measurement time (min), one panel per component and one
    colour per placement: drift shows as a trend within a placement
    (``FitResult.residuals_frame``: columns ``position, probe, ball, time_min, rx_um,
    ry_um, rz_um``)."""
    long = residuals.rename(columns={"rx_um": "x", "ry_um": "y", "rz_um": "z"}).melt(
        id_vars=["position", "probe", "ball", "time_min"], value_vars=["x", "y", "z"],
        var_name="component", value_name="residual_um")
    fig = px.scatter(long, x="time_min", y="residual_um", color="position",
                     facet_col="component", labels={"time_min": "time (min)",
                                                    "residual_um": "residual (µm)"})
    fig.for_each_annotation(lambda a: a.update(text=a.text.split("=")[-1]))
    return fig


def fig_parameter_trend(trend: pd.DataFrame, label: str) -> go.Figure:
    """One parameter over a machine's calibrations with its ± u bars (a history's trend
    table: columns ``label, date, value, u, unit``)."""
    tr = trend[trend["label"] == label]
    return px.scatter(tr, x="date", y="value", error_y="u",
                      labels={"value": f"{label} ({unit_label(tr['unit'].iloc[0])})"},
                      title=f"{label} over the calibrations (± u)")


def fig_error_map_change(grid: pd.DataFrame, component: str) -> go.Figure:
    """The change of the error map's ``component`` (µm) from the first calibration of a
    history to the last, at the ram reference point, one panel per height (a history's
    grid table: columns ``x_mm, y_mm, z_mm, de<c>_um, u_de<c>_um``)."""
    c = component
    return px.scatter(grid, x="x_mm", y="y_mm", color=f"de{c}_um", facet_col="z_mm",
                      facet_col_wrap=3, hover_data=[f"u_de{c}_um"],
                      labels={f"de{c}_um": f"change of e{c} (µm)"},
                      title="Error map change, first to last calibration "
                            "(ram reference point)")


def fig_mpe(result: MpeResult,
            title: str = "Length errors against the MPE (0.6 µm + L/600, L in mm)"
            ) -> go.Figure:
    """Length errors E (µm) against the certificate length L (mm): each with its ±U bar
    (k = 2), coloured by its ISO 14253-1 decision, between the ±MPE(L) lines."""
    colours = {"conforms": "#2ca02c", "inconclusive": "#ff7f0e",
               "does not conform": "#d62728"}
    fig = go.Figure()
    L = np.asarray(result.length_mm, float)
    order = np.argsort(L)
    for sign in (1, -1):
        fig.add_trace(go.Scatter(x=L[order], y=sign * np.asarray(result.mpe_um)[order],
                                 mode="lines", line={"color": "#444", "dash": "dash"},
                                 name="±MPE", showlegend=sign == 1, hoverinfo="skip"))
    for dec, colour in colours.items():
        sel = np.asarray(result.decision) == dec
        if not sel.any():
            continue
        text = [f"{p}: balls {a}-{b} ({d})" for p, a, b, d in zip(
            np.asarray(result.position)[sel], np.asarray(result.ball_a)[sel],
            np.asarray(result.ball_b)[sel], np.asarray(result.direction)[sel], strict=True)]
        fig.add_trace(go.Scatter(
            x=L[sel], y=np.asarray(result.error_um)[sel], mode="markers", name=dec,
            marker={"color": colour, "size": 5},
            error_y={"type": "data", "array": np.asarray(result.U_um)[sel], "thickness": 1,
                     "width": 0, "color": colour},
            text=text, hovertemplate="%{text}<br>L %{x:.1f} mm, E %{y:.2f} µm<extra></extra>"))
    fig.update_xaxes(title_text="certificate length L (mm)")
    fig.update_yaxes(title_text="length error E (µm)")
    return _layout(fig, title, height=420)


def fig_history(history: list) -> go.Figure:
    """RMS, χ²/dof, BIC and GP discrepancy amplitude as effects are added or removed.

    BIC is drawn relative to the first step: its absolute value (tens of thousands) only
    means something in differences, and an axis of "49.0645k / 49.065k" hid them."""
    fig = make_subplots(rows=1, cols=4, subplot_titles=("RMS (µm)", "χ²/dof",
                                                       "BIC − BIC of step 0",
                                                       "GP discrepancy (µm)"))
    if not history:
        return _layout(fig, "Diagnosis history (empty)", height=320)
    steps = [f"{i}: {h.get('change') or h.get('spec')}" for i, h in enumerate(history)]
    # tick labels name the change of each step (shortened), the hover gives it in full
    ticks = [str(h.get("change") or h.get("spec") or i)[:14] for i, h in enumerate(history)]
    for c, key in enumerate(("rms_um", "chi2_dof", "bic", "gp_amplitude_um"), start=1):
        y = [h.get(key) for h in history]
        y = [np.nan if v is None else v for v in y]
        if key == "bic":
            y = list(np.asarray(y, float) - y[0])
        fig.add_trace(go.Scatter(x=list(range(len(history))), y=y, mode="lines+markers",
                                 text=steps, showlegend=False,
                                 hovertemplate="%{text}<br>%{y:.4g}<extra></extra>"),
                      row=1, col=c)
        fig.update_xaxes(tickmode="array", tickvals=list(range(len(history))),
                         ticktext=ticks, tickangle=-30, row=1, col=c)
        if not np.isfinite(np.asarray(y, float)).any():
            fig.update_yaxes(showticklabels=False, row=1, col=c)
            fig.add_annotation(text="not computed", showarrow=False, row=1, col=c,
                               x=(len(history) - 1) / 2, y=0.5,
                               yref="y domain" if c == 1 else f"y{c} domain")
    return _layout(fig, "Diagnosis history: fit quality as effects are added", height=360)


def fig_detection_limits(evals: list, effects: list, height: int = 380) -> go.Figure:
    """Detection limits of plan evaluations (``plan`` JSON: each with ``name`` and
    ``detection_limits`` {effect: {"size", "unit"}}) as grouped bars, one panel per unit.

    Limits in µm, µrad, 10⁻⁶/K ... are not comparable, so each unit has its own log axis;
    each axis reaches a factor 4 above its tallest bar so that the value printed above it
    is never cut. A missing bar: the design cannot see that effect."""
    def limit(e, k):
        return (e["detection_limits"].get(k) or {})

    units = list(dict.fromkeys(next((limit(e, k)["unit"] for e in evals if limit(e, k)), "")
                               for k in effects))
    by_unit = {u: [k for k in effects if next((limit(e, k)["unit"] for e in evals
                                               if limit(e, k)), "") == u] for u in units}
    widths = [max(len(v), 1) for v in by_unit.values()] or [1]
    fig = make_subplots(rows=1, cols=max(len(units), 1), column_widths=widths,
                        subplot_titles=[unit_label(u) or "—" for u in units] or [""],
                        horizontal_spacing=0.06)
    colours = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b")
    for c, (u, ks) in enumerate(by_unit.items(), start=1):
        top = 0.0
        for j, e in enumerate(evals):
            y = [limit(e, k).get("size") for k in ks]
            top = max([top, *[v for v in y if v]])
            fig.add_bar(name=e["name"], x=ks, y=y, legendgroup=e["name"], showlegend=c == 1,
                        marker_color=colours[j % len(colours)], cliponaxis=False,
                        text=["—" if v is None else f"{v:.3g}" for v in y],
                        textposition="outside", row=1, col=c)
        if top > 0:
            bottom = min([limit(e, k).get("size") or top for e in evals for k in ks])
            fig.update_yaxes(type="log", range=[np.log10(bottom / 3), np.log10(top * 4)],
                             title_text=f"detection limit ({unit_label(u)})", row=1, col=c)
    fig.update_layout(barmode="group")
    return _layout(fig, "", height=height)


COLORWAY = ("#636efa", "#EF553B", "#00cc96", "#ab63fa", "#FFA15A", "#19d3f3", "#FF6692",
            "#B6E880", "#FF97FF", "#FECB52")
"""Plotly's default trace colours (template plotly_white), in order."""
PLACEMENT_SYMBOLS = ("circle-open", "square-open", "diamond-open", "triangle-up-open", "x",
                     "cross", "circle-open-dot", "square-open-dot")
"""One marker per placement in the 2-D placement views, in the placements' order."""


def fig_placement_views(dataset: Dataset) -> go.Figure:
    """The plate placements in three orthographic views of the machine volume (top XY,
    front XZ, side YZ; mm): the working volume's outline, every probed ball centre (the
    tip centre in the machine frame) with one colour and symbol per placement, one scale
    on both axes of a view. The hover text names placement, stylus, ball and the two
    coordinates."""
    rng = np.asarray(dataset.setup.range_mm, float)
    m = dataset.meas
    views = (("XY (top)", 0, 1), ("XZ (front)", 0, 2), ("YZ (side)", 1, 2))
    # each view as wide as its first axis's span, so one mm is one length in all three
    widths = [float(rng[i]) for _t, i, _j in views]
    fig = make_subplots(rows=1, cols=3, subplot_titles=[v[0] for v in views],
                        column_widths=widths, horizontal_spacing=0.06)
    shapes = []
    for c, (_title, i, j) in enumerate(views, start=1):
        n = "" if c == 1 else str(c)
        ax, bx = "XYZ"[i], "XYZ"[j]
        shapes.append({"type": "rect", "xref": f"x{n}", "yref": f"y{n}", "x0": 0.0,
                       "x1": float(rng[i]), "y0": 0.0, "y1": float(rng[j]),
                       "line": {"color": "grey", "dash": "dash", "width": 1},
                       "name": f"working volume {rng[i]:g} × {rng[j]:g} mm"})
        for k, (pos, g) in enumerate(m.groupby("position", sort=False)):
            fig.add_trace(go.Scatter(
                x=g[f"m{ax.lower()}_mm"], y=g[f"m{bx.lower()}_mm"], mode="markers",
                name=str(pos), legendgroup=str(pos), showlegend=c == 1,
                marker={"symbol": PLACEMENT_SYMBOLS[k % len(PLACEMENT_SYMBOLS)], "size": 7,
                        "color": COLORWAY[k % len(COLORWAY)]},
                customdata=np.column_stack([g["probe"].astype(str), g["ball"].astype(str)]),
                hovertemplate=f"{pos}, probe %{{customdata[0]}}, ball %{{customdata[1]}}: "
                              f"{ax} %{{x:.1f}}, {bx} %{{y:.1f}} mm<extra></extra>"),
                row=1, col=c)
        fig.update_xaxes(title_text=f"{ax} (mm)", row=1, col=c)
        fig.update_yaxes(title_text=f"{bx} (mm)", scaleanchor=f"x{n}", row=1, col=c)
    fig.update_layout(shapes=shapes)
    return _layout(fig, None, height=360)


def fig_placements(dataset: Dataset, certificate_xyz: ArrayLike | None = None) -> go.Figure:
    """3D view of the plate placements (measured ball centres) in the machine volume."""
    rng = np.asarray(dataset.setup.range_mm, float)
    fig = go.Figure()
    # machine volume wireframe
    corners = np.array([[x, y, z] for x in (0, rng[0]) for y in (0, rng[1]) for z in (0, rng[2])])
    edges = [(0, 1), (0, 2), (0, 4), (1, 3), (1, 5), (2, 3), (2, 6), (3, 7), (4, 5), (4, 6),
             (5, 7), (6, 7)]
    xs: list = []
    ys: list = []
    zs: list = []
    for a, b in edges:
        for arr, k in ((xs, 0), (ys, 1), (zs, 2)):
            arr += [corners[a, k], corners[b, k], None]
    fig.add_trace(go.Scatter3d(x=xs, y=ys, z=zs, mode="lines", name="working volume",
                               line={"color": "grey", "width": 2}, hoverinfo="skip"))
    m = dataset.meas
    for pos, g in m.groupby("position", sort=False):
        fig.add_trace(go.Scatter3d(
            x=g["mx_mm"], y=g["my_mm"], z=g["mz_mm"], mode="markers", name=str(pos),
            marker={"size": 3},
            text=g["probe"].astype(str).radd("probe ") + ", ball " + g["ball"].astype(str),
            hovertemplate="%{text}<br>(%{x:.1f}, %{y:.1f}, %{z:.1f}) mm<extra>"
                          + str(pos) + "</extra>"))
    # the camera a little further out than plotly's default, or the near corner of the
    # volume and its tick labels are clipped
    fig.update_layout(scene={"xaxis_title": "X (mm)", "yaxis_title": "Y (mm)",
                             "zaxis_title": "Z (mm)", "aspectmode": "data",
                             "camera": {"eye": {"x": 1.6, "y": 1.6, "z": 1.0}}})
    return _layout(fig, "Plate placements in the machine volume (mm)", height=560)


def fig_surface_grid(xg: ArrayLike, yg: ArrayLike, values: ArrayLike, *, title: str, unit: str,
                     points: ArrayLike | None = None, colorscale: str = "RdBu_r",
                     xlabel: str = "X (mm)", ylabel: str = "Y (mm)",
                     zrange: tuple[float, float] | None = None) -> go.Figure:
    """A heatmap of a quantity over a grid (mm) with the measured points on top.

    A diverging colour scale (the default, for signed errors) is centred on zero so white
    means no error; ``zrange`` = (min, max) fixes the scale so that maps drawn side by
    side (kinematic model, GP, measurement) can be compared by colour.
    """
    scale = {}
    if zrange is not None:
        scale = {"zmin": float(zrange[0]), "zmax": float(zrange[1])}
    elif isinstance(colorscale, str) and colorscale.startswith("RdBu"):
        scale = {"zmid": 0.0}
    fig = go.Figure(go.Heatmap(x=xg, y=yg, z=values, colorscale=colorscale, **scale,
                               colorbar={"title": {"text": unit}},
                               hovertemplate="%{x:.0f} mm, %{y:.0f} mm<br>%{z:.3f} "
                                             + unit + "<extra></extra>"))
    pts = None if points is None else np.asarray(points, float)
    if pts is not None and len(pts):
        fig.add_trace(go.Scatter(x=pts[:, 0], y=pts[:, 1], mode="markers",
                                 name="measured points",
                                 marker={"size": 5, "color": "black", "symbol": "x"}))
    # equal scales without padding the x range: shrink the plot area instead
    fig.update_xaxes(title_text=xlabel, constrain="domain")
    fig.update_yaxes(title_text=ylabel, scaleanchor="x", scaleratio=1)
    return _layout(fig, title, height=420)
