"""Uncertainty page: U1/U2/U3, uncertainty maps, Monte Carlo check, budget and MPE."""

from dataclasses import replace

import numpy as np
import pandas as pd
import streamlit as st

from cmm_core import analysis as A
from cmm_core import gum
from cmm_core.model import error_at, monte_carlo_error, rigid_removed_error_u
from pages.ui import cached, calls, widgets

st.title("Uncertainty")
st.caption("Standard uncertainties (k = 1) unless marked U (k = 2). U1-U3 remove the "
           "rigid-body freedoms, as the thesis does (a rigid motion of the workpiece is not a "
           "CMM error); the map below does not: it is the uncertainty of the error at each "
           "point as a correction would use it, which includes the poorly fixed origin and "
           "orientation of the machine widgets.")
ds, r = cached.require_fit()
s = st.session_state
args = cached.fit_key()

widgets.misfit_banner(r)
st.subheader("U1, U2, U3 (thesis tables 4.1-4.3)")
c1, c2 = st.columns(2)
n_random = c1.number_input("Random points", 20, 2000, 200, step=20, key="w_u_npts")
seed = c2.number_input("Seed", 0, 10_000, 0, key="w_u_seed")
summary = calls.safe(cached.cached_uncertainty, args, int(n_random), int(seed), r,
                 what="Uncertainty evaluation")
if summary is not None:
    rows = []
    for lab, desc in (("U1_um", "U1: ball-centre coordinates"),
                      ("U2_um", "U2: CMM error in the evaluated region"),
                      ("U3_um", "U3: CMM error in the whole working volume")):
        v = getattr(summary, lab)
        if v:  # a quantity not evaluated is left out; the caption below says why
            rows.append({"quantity": desc, **{f"u_{a} (µm, k = 1)": v[a] for a in "xyz"}})
            if r.fails_chi2_test:  # the noise part scaled, the certificate's as it is
                vi = summary.inflated[lab]
                rows[-1].update({f"u_{a} × Birge (µm)": vi[a] for a in "xyz"})
    if rows:
        widgets.dataframe(pd.DataFrame(rows), hide_index=True, key="u_table",
                     column_config={c_: st.column_config.NumberColumn(format="%.4f")
                                    for c_ in rows[0] if c_ != "quantity"})
    else:
        # numbers that do not exist are not shown as "None": say why instead
        st.warning("U1-U3 are not evaluated: the data do not determine every parameter, so "
                   "the uncertainties are unbounded.")
    st.caption(summary.message)

st.subheader("Uncertainty map")
obs = r.problem.obs
rng = np.asarray(obs.range_mm, float)
c1, c2, c3, c4 = st.columns(4)
zval = c1.slider("Z of the XY plane (mm)", 0.0, float(rng[2]), float(round(rng[2] / 2)),
                 step=10.0, key="w_u_z")
probe = c2.selectbox("Probe", obs.probes, key="w_u_probe")
comp = c3.radio("Component", ["x", "y", "z"], horizontal=True, key="w_u_comp")
SHOW = {"shape": "rigid part removed", "absolute": "absolute"}
show = c4.radio("Uncertainty U (k = 2)", list(SHOW), format_func=SHOW.get, key="w_u_show",
                help="Rigid part removed: the uncertainty of the error's shape over the plane "
                     "(what lengths and form measured there carry, as U2/U3). Absolute: "
                     "also the common translation and rotation, fixed only through the "
                     "error functions' zero at the axis origins.")

@st.cache_data(show_spinner=False, max_entries=64)
def error_grid(args, z, probe, n, _r):

    xs = np.linspace(0, _r.problem.obs.range_mm[0], n)
    ys = np.linspace(0, _r.problem.obs.range_mm[1], n)
    X, Y = np.meshgrid(xs, ys)
    pts = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, z)])

    e, u = error_at(_r, pts, probe)
    return xs, ys, e, u, rigid_removed_error_u(_r, pts, probe)


with calls.guarded("Uncertainty map"):
    n = 31
    xs, ys, e, u, u_shape = error_grid(args, float(zval), probe, n, r)
    a = "xyz".index(comp)
    x_meas = obs.r_mm - obs.p_mm
    near = np.abs(x_meas[:, 2] - zval) < 60
    if show == "shape":
        vals, title = 2 * u_shape[:, a], f"U(e{comp}), k = 2, rigid part removed"
    else:
        vals, title = 2 * u[:, a], f"U(e{comp}), k = 2, absolute"
    if np.isnan(vals).all():
        st.warning("The uncertainty is unbounded: the data do not determine every model "
                   "parameter (see the Kinematic model page).")
    else:
        # the error and its uncertainty side by side: together they fill the page width,
        # and each colour bar stays next to its map
        m1, m2 = st.columns(2)
        with m1:
            widgets.show(widgets.beside_map(A.fig_surface_grid(
                xs, ys, e[:, a].reshape(n, n), title=f"Error e{comp} (µm), probe {probe}",
                unit="µm", points=x_meas[near], colorscale="RdBu_r")), chart_key="u_error_map",
                width_px=640, width="stretch")
        with m2:
            widgets.show(widgets.beside_map(A.fig_surface_grid(
                xs, ys, vals.reshape(n, n), title=f"{title} (µm)", unit="µm",
                points=x_meas[near], colorscale="Viridis")), chart_key="u_map", width_px=640,
                width="stretch")
        st.caption(f"XY plane at Z = {zval:g} mm; scale readings in mm; × marks measured "
                   "points within 60 mm of the plane. The error is zero at the axis origins "
                   "by convention.")

st.subheader("Monte Carlo check of the propagated uncertainty")
c1, c2 = st.columns([1, 3])
trials = c1.number_input("Trials", 100, 200000, 1000, step=100, key="w_mc_trials")
run_mc = c1.button("Run Monte Carlo", key="run_mc")
mc_key = (args, int(trials), probe)
if run_mc:
    if r.unidentifiable:
        st.warning("Not run: the data do not determine every parameter.")
    else:
        rs = np.random.default_rng(1)
        pts = np.column_stack([rs.uniform(0, rng[0], 40), rs.uniform(0, rng[1], 40),
                               rs.uniform(0, rng[2], 40)])

        bar = st.progress(0.0, text="Monte Carlo…")
        _, u_mc, u_lin = monte_carlo_error(r, pts, probe, trials=int(trials),
                                           progress=lambda f, t: bar.progress(f, text=t))
        bar.empty()
        s["mc_result"] = (mc_key, u_lin, u_mc)
res = s.get("mc_result")
if res is not None and res[0] == mc_key:
    _, u_lin, u_mc = res
    ratio = u_mc / np.where(u_lin > 0, u_lin, np.nan)
    c2.metric("Monte Carlo u / propagated u (median over 40 points × 3 axes)",
              f"{np.nanmedian(ratio):.3f}")
    c2.caption(f"Range {np.nanmin(ratio):.3f}-{np.nanmax(ratio):.3f}. Near 1: the linear "
               "propagation (GUM) holds; the model is nearly linear in its parameters. "
               "This checks linearity only, not whether the model fits: "
               + ("it fails its χ² test, so both u are too small by about "
                  f"×{r.birge_ratio:.2f}." if r.fails_chi2_test else
                  "the fit passes its χ² test."))
else:
    c2.caption("Samples the kinematic coefficients from their covariance and compares the "
               "spread of the error at 40 random points with the propagated uncertainty. "
               "Changing any input cancels a running check.")

st.subheader("Ball-plate calibration budget (thesis eq. 3.14-3.29)")
st.caption("The budget of calibrating a ball plate by the thesis's procedure, a calculator "
           "of its own: its inputs start at the environment recorded with thesis tables "
           "6.1-6.6, "
           "not at the dataset loaded; set them for your calibration.")
with calls.guarded("Budget"):
    recs = {r.position: r for r in (*gum.THESIS_ENVIRONMENT,
                                    gum.average_environment())}
    c = st.columns(5)
    rec = c[0].selectbox("Environment record", list(recs), index=len(recs) - 1,
                         key="w_b_record", help="Temperatures and humidities written "
                         "above thesis tables 6.1-6.6, or their average.")
    base = gum.inputs_from_record(recs[rec])
    length = c[1].number_input("Length L (mm)", 1.0, 2000.0, float(base.length_mm),
                               key="w_b_length")
    s_lx = c[2].number_input("Repeatability s (µm)", 0.0, 50.0, float(base.s_lx_um),
                             key="w_b_s")
    n_rep = c[3].number_input("Repeats n", 2, 100, int(base.n_repeats), key="w_b_n")
    p_cov = c[4].selectbox("Coverage probability", [0.95, 0.9545, 0.99], key="w_b_p")
    c = st.columns(4)
    p_pa = c[0].number_input("Air pressure (Pa)", 60000.0, 120000.0, float(base.p_Pa),
                             key="w_b_p_pa")
    align = c[1].number_input("Plate misalignment (µm)", 0.0, 500.0,
                              float(base.alignment_mm * 1e3), key="w_b_align")
    cte = c[2].number_input("Plate CTE (1e-6/K)", 0.0, 30.0, float(base.cte_per_K * 1e6),
                            key="w_b_cte")
    air_on = c[3].checkbox("Include air refractive index terms", value=base.include_air,
                           key="w_b_air")

    inp = replace(base, length_mm=float(length), s_lx_um=float(s_lx),
                  n_repeats=int(n_rep), p_Pa=float(p_pa), alignment_mm=align * 1e-3,
                  cte_per_K=cte * 1e-6, include_air=bool(air_on))
    b = gum.ballplate_budget(inp, coverage_probability=float(p_cov))
    g = b.gum
    m = st.columns(4)
    m[0].metric("u_c (µm)", f"{g.u_c:.4f}")
    m[1].metric("ν_eff (Welch-Satterthwaite)", "∞" if not np.isfinite(g.nu_eff)
                else f"{g.nu_eff:.1f}")
    m[2].metric("k", f"{g.k:.3f}")
    m[3].metric(f"U (µm, p = {p_cov})", f"{g.U:.4f}")
    btab = pd.DataFrame(b.table())
    if "dof" in btab:
        # infinite degrees of freedom (Type B): the symbol, not "Infinity"
        btab["dof"] = [("∞" if not np.isfinite(v) else f"{v:g}") if isinstance(v, (int, float))
                       else v for v in btab["dof"]]
    widgets.dataframe(btab, hide_index=True, key="budget_table",
                column_config={"share": st.column_config.ProgressColumn(
                    "variance share", min_value=0.0, max_value=1.0, format="%.3f")})
    st.caption("u in the unit of each input, c in µm per unit, u_y = |c|·u in µm. Values "
               "not printed in the thesis are documented assumptions (see "
               "cmm_core.budget).")
    mc1, mc2 = st.columns([1, 3])
    bt = mc1.number_input("Monte Carlo trials", 10_000, 5_000_000, 200_000, step=50_000,
                          key="w_b_trials")
    if mc1.button("Run GUM-S1 Monte Carlo", key="run_budget_mc"):
        bar = mc2.progress(0.0, text="Monte Carlo (JCGM 101)…")

        def _progress(frac):
            bar.progress(min(max(float(frac), 0.0), 1.0),
                         text=f"Monte Carlo (JCGM 101): {100 * frac:.0f} %")

        res = gum.monte_carlo(b.contributions, trials=int(bt), correlations=b.correlations,
                              coverage_probability=float(p_cov), seed=1,
                              progress=_progress)
        bar.empty()
        s["budget_mc"] = ((rec, length, s_lx, n_rep, p_cov, p_pa, align, cte, air_on, bt),
                          res)
    mcr = s.get("budget_mc")
    if mcr is not None and mcr[0] == (rec, length, s_lx, n_rep, p_cov, p_pa, align, cte,
                                      air_on, bt):
        res = mcr[1]
        lo, hi = res.interval_shortest
        mc2.success(f"Monte Carlo ({res.trials} trials, {res.status}): u = {res.u:.4f} µm, "
                    f"shortest {100 * p_cov:g} % interval [{lo:.4f}, {hi:.4f}] µm "
                    f"(half-width {(hi - lo) / 2:.4f} µm vs GUM U = {g.U:.4f} µm).")
    # lazy (issue 27): the budget over every length is computed and drawn only while open
    with st.expander("U(L) over the plate's lengths", key="w_u_ul_open",
                     on_change="rerun") as ul_box:
        if ul_box.open:
            ld = gum.budget_vs_length(inp, coverage_probability=float(p_cov))
            widgets.show(A.fig_budget_vs_length(ld), chart_key="budget_UL")
            st.caption(f"Least-squares fit U(L)² ≈ a² + (b·L)²: a = {ld.fit_a_um:.3f} µm, "
                       f"b = {ld.fit_b_per_mm * 1e3:.3f} µm/m.")
with st.expander("Refractive index of air (modified Edlén, Birch and Downs 1994)"):
    c = st.columns(4)
    tC = c[0].number_input("T (°C)", 0.0, 40.0, 20.0, key="w_air_t")
    pPa = c[1].number_input("p (Pa)", 60000.0, 120000.0, 101325.0, key="w_air_p")
    rh = c[2].number_input("RH (%)", 0.0, 100.0, 50.0, key="w_air_rh")
    lam = c[3].number_input("λ (nm)", 350.0, 1100.0, 632.99, key="w_air_l",
                            help="Vacuum wavelength; the Edlén equation holds 350-1100 nm.")
    n_air = calls.safe(gum.refractive_index_edlen, tC, pPa, rh, lam, what="Edlén")
    if n_air is not None:
        st.metric("n − 1", f"{float(n_air) - 1:.6e}")


def show_mpe(out, skipped, u_src, sig):
    """Counts, plot, table and caption of an MPE check."""
    with calls.guarded("MPE plot and table"):
        cnt = out.counts
        m = st.columns(len(cnt) + 1)
        for c_, (k_, v) in zip(m, cnt.items(), strict=False):
            c_.metric(k_, v)
        m[-1].metric("max |E| (µm)", f"{out.max_abs_error_um():.2f}")
        widgets.plot("mpe", (args, u_src, sig), A.fig_mpe, out, chart_key="fig_mpe")
        widgets.dataframe(pd.DataFrame(out.rows()), hide_index=True, key="mpe_table",
                     column_config={"length_mm": st.column_config.NumberColumn(format="%.3f"),
                                    "error_um": st.column_config.NumberColumn(format="%.2f"),
                                    "U_um": st.column_config.NumberColumn(format="%.2f"),
                                    "mpe_um": st.column_config.NumberColumn(format="%.2f")})
        st.caption("Length errors E = measured − certificate length for every ball pair on a "
                   "row, column or diagonal, per position and probe (outliers included: they "
                   "are real readings). ISO 14253-1: conforms when |E| + U ≤ MPE, does not "
                   "conform when |E| − U > MPE, otherwise inconclusive. U (k = 2) is from "
                   + gum.U_SOURCES[u_src]
                   + (f" (σ = {sig:g} µm)." if u_src == "test" else ".")
                   + (f" Skipped (missing balls): {', '.join(skipped)}." if skipped else ""))
        # ISO 14253-1 needs |E| + U <= MPE: where U alone reaches the MPE nothing can conform
        cannot = np.asarray(out.U_um) >= np.asarray(out.mpe_um)
        if cannot.any():
            st.info(f"{int(cannot.sum())} of {cannot.size} lengths cannot conform whatever "
                    "their error: their U (k = 2) is at least the MPE, so every such length "
                    "is at best inconclusive. A smaller U (a better certificate, a smaller "
                    "repeatability, repeated measurements) is needed to show conformity "
                    "there.")


st.subheader("MPE check (0.6 µm + L/600, L in mm)")
if gum.plate_side(ds.certificate) is None:
    st.info("The MPE check needs the certificate of a square ball plate (n × n balls, "
            "n from 3, numbered row by row).")
else:
    out, skipped = None, []
    with calls.guarded("MPE check"):
        U_SOURCES = gum.U_SOURCES
        u_src = st.radio("Uncertainty U of each length error", list(U_SOURCES),
                         format_func=U_SOURCES.get, horizontal=True, key="w_mpe_u",
                         help="ISO 14253-1 decides with the uncertainty of the test: the "
                              "plate's calibrated lengths (√(0.26² + (1.9e-3 L)²) µm, k = 2, "
                              "thesis appendix 1) and the repeatability of the two probed "
                              "centres. The thesis's CMM specification is offered for "
                              "comparison.")
        sig = float(s["sigma_um"])
        out, skipped = gum.check_dataset(ds, u_source=u_src, sigma_um=sig)
    if out is None:
        st.info("No position has every ball measured: nothing to check.")
    else:
        show_mpe(out, skipped, u_src, sig)
