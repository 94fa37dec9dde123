"""Kinematic model page: choose the model, see the fitted error functions and deviations."""

import numpy as np
import pandas as pd
import streamlit as st

from cmm_core import analysis as A
from cmm_core.machine import ERROR_NAMES
from cmm_core.model import (
    GROUPS,
    PHYSICAL,
    distinct_words,
    parameter_name,
    parse_spec,
    setup_layout,
)
from cmm_core.model import residuals_frame as instrument_residuals
from cmm_core.model import summary as instrument_summary
from cmm_core.units import label as unit_label
from pages.ui import cached, calls, state, widgets

st.title("Kinematic model")
widgets.flash()
ds = cached.require_dataset()
s = st.session_state
st.caption("The 21-error local kinematic model of the machine's layout, here "
           f"`{setup_layout(ds.setup)}` (setup machine.layout, docs/layouts.md; the moving "
           "bridge FXYZ is thesis eq. 4.13), Chebyshev polynomials over each axis stroke, "
           "fitted by Gauss-Newton with the rigid placement of every position"
           + (" and the instrument files' rows." if s.get("instruments") else "."))

with st.container(border=True):
    c1, c2, c3 = st.columns([3, 3, 2])
    pos_all, prb_all = ds.positions, ds.probes
    if s["positions"] is not None and not set(s["positions"]) <= set(pos_all):
        s["positions"] = None
    if s["probes"] is not None and not set(s["probes"]) <= set(prb_all):
        s["probes"] = None
    if "w_positions" not in s:
        s["w_positions"] = list(s["positions"] or pos_all)
    if "w_probes" not in s:
        s["w_probes"] = list(s["probes"] or prb_all)
    sel_pos = c1.multiselect("Positions", pos_all, key="w_positions")
    sel_prb = c2.multiselect("Probes", prb_all, key="w_probes")
    s["positions"] = None if set(sel_pos) == set(pos_all) else list(sel_pos)
    s["probes"] = None if set(sel_prb) == set(prb_all) else list(sel_prb)
    widgets.bind("order", c3.selectbox, "Polynomial order", options=[1, 2, 3, 4, 5],
           help="Default Chebyshev order of every error function (straightness has no linear "
                "term, so order 2 is quadratic).")
    c1, c2, c3 = st.columns([4, 3, 1])
    spec_txt = widgets.bind("spec", c1.text_input, "Model (effect list)",
                      help="Comma-separated, applied left to right: the 21 names (dxx … syz), "
                           "groups " + ", ".join(GROUPS) + ", name:order, -name to remove, "
                           "physical effects " + ", ".join(PHYSICAL) + ". Examples: "
                           "`kinematic21,-sxy`, `translational,squareness`, "
                           "`kinematic21,plate_sag`.")
    widgets.bind("plate", c2.selectbox, "Plate geometry", options=list(state.PLATE_CHOICES),
           format_func=state.PLATE_CHOICES.get)
    widgets.bind("sigma_um", c3.number_input, "σ (µm)", min_value=0.01, max_value=100.0,
           step=0.1, help="Measurement repeatability: weights, χ² and uncertainties.")
    try:
        model = parse_spec(spec_txt, default_order=int(s["order"]))
        full = widgets.spec_expansion(spec_txt)
        st.caption(f"{len(model.active)} error functions; effects: "
                   f"{', '.join(model.effects) or 'none'}"
                   + ("; hover the ? for the explicit form" if full else ""),
                   help=f"Explicit form: {full}" if full else None)
    except ValueError as exc:
        st.error(f"Model: {exc}")
        st.stop()

if not sel_pos or not sel_prb:
    st.warning("Choose at least one position and one probe.")
    st.stop()
r = cached.current_fit()
if r is None:
    st.stop()

c = st.columns(6)
c[0].metric("RMS residual", f"{r.rms_um:.3f} µm")
c[1].metric("χ²/dof", f"{r.chi2_dof:.2f}")
c[2].metric("BIC", f"{r.bic:.1f}")
c[3].metric("Ball centres", r.n_obs, help="Probed ball centres fitted, three coordinates "
            "each (two for a hole plate): the degrees of freedom count coordinates.")
c[4].metric("Parameters (rank)", r.rank)
c[5].metric("Iterations", r.iterations)
# green only when the fit converged and explains the data (χ²/dof near 1)
(st.success if r.status == "converged" and not r.fails_chi2_test else st.warning)(r.message)

st.subheader("Identifiability")
if r.unidentifiable:
    st.warning(f"The data cannot determine {len(r.null_combinations)} parameter "
               "combination(s). They are reported, not silently zeroed:")
    # in words, each sentence once, in full (a table cell cuts long text)
    st.markdown("\n".join(f"- {w}" + (f" ({n} combinations read so)" if n > 1 else "")
                           for w, n in distinct_words(r.null_words)))
    with st.expander("The combinations with their weights, scaled so the largest is 1"):
        widgets.dataframe(pd.DataFrame({"undetermined combination": r.null_combinations}),
                          hide_index=True, key="null_combos")
    st.caption("Parameters involved: " + ", ".join(r.unidentifiable))
else:
    st.success(f"Every parameter is determined by the data (numerical rank {r.rank}, "
               f"relative tolerance {r.rank_rtol:g} on the singular values).")

def error_function_grid(r, show, cols, truth):
    """The grid of fitted error functions, laid out for the page: the legend under the
    title rather than 15 % of the figure's height below the last row (a blank band of
    some 270 px under seven rows), and the bottom margin just what the axis titles need."""
    fig = A.fig_error_functions(r, show, cols, truth)
    fig.update_layout(legend={"orientation": "h", "yref": "container", "y": 1.0,
                              "yanchor": "top", "x": 1.0, "xanchor": "right"},
                      margin={"t": 70, "b": 40})
    return fig


# the bands, the parameter u and the maps below are σ-based: say whether to trust them
widgets.misfit_banner(r)
truth = s.get("sim_truth")
# lazy tabs: a hidden tab's figure is neither built nor sent, so the page opens with the
# one figure in view (a browser drew all four, about a second of Plotly, issue 27); the
# open tab is in the URL (bind), so a reload opens it again
tabs = st.tabs(["Error functions", "Deviation plots", "Parameters", "Residuals"],
               key="w_kin_tab", on_change="rerun",
               bind="query-params")
with tabs[0], calls.guarded("Error functions"):
    present = [n for n, _ in r.terms.functions]
    show = st.multiselect("Show", present, default=present)
    true_now = truth["truth"] if truth and truth.get("key") == s["ds_key"] else None
    if tabs[0].open:
        widgets.plot("errfun", (cached.fit_key(), tuple(show), true_now is not None),
                   error_function_grid, r, show, 3, true_now, chart_key="fig_errfun",
                   width="stretch")
    st.caption("Translational errors in µm, rotations in µrad, squareness as an angle in "
               "µrad; grey bands: 95 % (k = 2) from the parameter covariance; the blue tint "
               "spans the measured scale readings (outside it the curve extrapolates)"
               + ("; dashed: the simulation's true function." if true_now else "."))

with tabs[1], calls.guarded("Deviation plots"):
    c1, c2 = st.columns([1, 3])
    pos_fit = r.problem.obs.positions
    position = c1.selectbox("Position", pos_fit, key="w_dev_position")
    widgets.bind("magnification", c2.slider, "Magnification", min_value=100.0, max_value=10000.0,
           step=100.0, format="×%.0f")
    if tabs[1].open:
        widgets.plot("deviation", (cached.fit_key(), position, float(s["magnification"])),
                   A.fig_deviation, r, position, float(s["magnification"]),
                   chart_key="fig_deviation")
    st.caption("Plate frame, mm: nominal ball centres (certificate or fitted plate), measured "
               "points and the points the model predicts, deviations magnified (thesis "
               "figures 4.8-4.10).")

def _adopt_scatter(sigma_um):
    # the widget key must change with the value, before the widget is drawn again
    s["sigma_um"] = s["w_sigma_um"] = float(min(max(sigma_um, 0.01), 100.0))


with tabs[2], calls.guarded("Parameter table"):
    # drawn only while open: its data grid's scripts (1.3 MB) would load with the
    # page's first visit from a tab no one has opened (issue 41: a first visit under 1 s)
    if tabs[2].open:
        pf = r.parameters_frame()
        pf.insert(1, "name", [parameter_name(lab) for lab in pf["parameter"]])
        pf["determined"] = ~pf["parameter"].isin(r.unidentifiable)
        pf["U (k=2)"] = 2 * pf["u"]
        birge = r.birge_ratio
        if birge > 1.05:
            # the scatter exceeds the stated σ: scale u by √(χ²/dof) (Birge 1932), the
            # figure to quote until the missing effect is found
            pf["u, Birge-scaled"] = r.u_inflated
            st.info(f"Birge ratio √(χ²/dof) = {birge:.2f} (of the tested statistic): the "
                    f"residuals scatter {birge:.2f} times what the stated σ allows, so the noise "
                    "part of u is too small. The column *u, "
                    "Birge-scaled* is the honest standard uncertainty until the model explains "
                    "the data (see Compare and diagnose). The bands, maps, U1-U3 and exports "
                    "use σ; to carry the scaling everywhere, adopt the observed scatter as σ.")
            st.button(f"Use the observed scatter as σ ({s['sigma_um'] * birge:.3g} µm)",
                      key="adopt_scatter", on_click=_adopt_scatter, args=(s["sigma_um"] * birge,),
                      help="Sets σ to σ·√(χ²/dof): every uncertainty on every page and in the "
                           "exports is then Birge-scaled, and χ²/dof becomes 1.")
        if truth and truth.get("key") == s["ds_key"]:
            pf["true (simulation)"] = pf["parameter"].map(truth["truth"])
            # the check a metrologist makes first: |z| < 2-3 for nearly every parameter
            pf["(value − true)/u"] = (pf["value"] - pf["true (simulation)"]) / pf["u"]
        blocks = st.multiselect("Blocks", list(dict.fromkeys(pf["block"])),
                                default=[b for b in dict.fromkeys(pf["block"])
                                         if b not in ("rotation", "translation")],
                                )
        view = pf[pf["block"].isin(blocks)].assign(unit=lambda d: d["unit"].map(
            unit_label))
        widgets.dataframe(view, hide_index=True, key="param_table",
                     column_config={"value": st.column_config.NumberColumn(format="%.4f"),
                                    "u": st.column_config.NumberColumn("u (k=1)", format="%.4f"),
                                    "U (k=2)": st.column_config.NumberColumn(format="%.4f"),
                                    "(value − true)/u": st.column_config.NumberColumn(
                                        format="%.2f"),
                                    "u, Birge-scaled": st.column_config.NumberColumn(
                                        format="%.4f")})
        st.caption("Units per row: µm (translational, placement translation, plate), µrad "
                   "(rotations, squareness, placement rotation). `plate_sag.uu`, `.vv` are bowl "
                   "heights at the plate edge (µm, middle of the u and v edges against the "
                   "centre), `.uv` the twist at a corner (µm). `drift` is in µm/h"
                   + ("." if state.dataset().meas.get("time_min", pd.Series([None])).notna().all() else
                      ": these data have no time_min column, so time is the row order at one "
                      "minute per row (µm/h = µm per 60 rows)."))

with tabs[3], calls.guarded("Residuals"):
    if tabs[3].open:
        widgets.plot("pattern", cached.fit_key(), A.fig_pattern, r.table, r.residuals_um,
                   "Residuals per observation (µm)", chart_key="fig_resid")
        widgets.dataframe(A.residual_summary(r), hide_index=True, key="resid_summary")
        rf = r.residuals_frame()
        worst = rf.assign(norm_um=np.linalg.norm(r.residuals_um, axis=1)).nlargest(
            10, "norm_um")
        st.caption("Largest residuals (µm), with the file and row each came from:")
        widgets.dataframe(worst, hide_index=True, key="resid_worst")

def instruments_section(r):
    """The instruments fitted with the plate: their residuals and the uncertainty gain."""

    st.subheader("Instruments fitted with the plate")
    table, readings = A.instrument_tables(instrument_summary(r), instrument_residuals(r))
    widgets.dataframe(table, hide_index=True, key="instrument_summary",
                column_config={"chi2": st.column_config.NumberColumn("χ²", format="%.1f"),
                               "RMS residual/u": st.column_config.NumberColumn(format="%.2f"),
                               "RMS residual (µm)": st.column_config.NumberColumn(
                                   format="%.3f")})
    st.caption("Residual: the model's prediction minus the reading (µm), each laser run's "
               "zero (and a straightness run's slope) removed; RMS residual/u near 1 when "
               "the model explains the instrument as its u says.")
    widgets.dataframe(readings, hide_index=True, key="instrument_residuals",
                column_config={c_: st.column_config.NumberColumn(format="%.3f")
                               for c_ in ("residual (µm)", "u (µm)", "residual/u")})
    alone = cached.current_fit(instruments=False, show_error=False)
    if alone is None:
        st.warning("The fit of the plate alone failed: no uncertainty gain to show.")
        return
    st.markdown("**Uncertainty gain**")
    gain = A.uncertainty_gain(r, alone)
    st.caption("Standard uncertainty (k = 1) of each kinematic coefficient from the plate "
               "alone and with the instruments in the same fit (same model, σ and "
               "selection); the gain is their ratio, how many times smaller the "
               "instruments make it, largest first.")
    widgets.dataframe(gain, hide_index=True, key="instrument_gain",
                column_config={"u plate only": st.column_config.NumberColumn(format="%.4f"),
                               "u with instruments": st.column_config.NumberColumn(
                                   format="%.4f"),
                               "gain": st.column_config.NumberColumn("gain ×",
                                                                     format="%.2f")})


if s.get("instruments"):
    with calls.guarded("Instruments"):
        instruments_section(r)

with st.expander("The 21 error names"):
    st.write(", ".join(ERROR_NAMES))
