"""Gaussian process page: GP surfaces beside the kinematic model, and the chapter 7
comparison (kinematic vs GP vs measurement) done honestly."""

from dataclasses import replace

import numpy as np
import pandas as pd
import streamlit as st

from cmm_core import analysis as A
from cmm_core.analysis import (
    compare_models,
    coverage_reasons,
    measured_error_from_residuals_um,
    placement_plane_grid,
)
from cmm_core.gp import gp_components, predict_grid
from cmm_core.model import residual_u
from pages.ui import cached, calls, widgets

st.title("Gaussian process")
st.caption("A GP over the measured errors at the ball centres (thesis chapter 5): zero mean, "
           "quadratic mean (eq. 5.11) or the kinematic model as mean; squared-exponential "
           "kernel, isotropic or ARD.")
ds, r = cached.require_fit()
s = st.session_state


@st.cache_data(show_spinner=False, max_entries=16)
def measured_errors(key, _ds, _instruments=()):
    """Measured error at every observation: minus the residual of a rigid-placement-only
    fit (µm, machine axes), with the points (tip centres, mm) and placements removed."""
    rig = cached.cached_fit(key.with_spec("rigid"), _ds, _instruments)
    obs = rig.problem.obs
    return (obs.r_mm, measured_error_from_residuals_um(rig.residuals_um),
            rig.table[["position", "probe", "ball"]])


@st.cache_data(show_spinner=False, max_entries=32)
def kinematic_residual_u(args, _r):
    """Standard uncertainty of "kinematic model minus measurement" at each fitted ball.
    That difference is the fit's residual: the model was fitted to this very ball, so
    the two share its noise and the difference varies as σ√(1 − h_ii), less than
    √(u_model² + σ²) (``uncertainty.residual_u``)."""
    return residual_u(_r)


@st.cache_resource(show_spinner=False, max_entries=48)
def fit_gp_component(args, target, mean, kernel, restarts, comp, probe_input, _points,
                     _values, _probe):
    """One component's GP (cached per component so a progress bar can show between them
    and a changed input cancels the rest). ``target`` names what ``_values`` holds
    (``measured`` errors or ``kinematic`` residuals): the values are not hashed, so the
    name must be part of the key. With ``probe_input`` the inputs are the ram position
    and the probe offset ``_probe`` (one noise level per stylus)."""
    return gp_components(_points, np.asarray(_values, float)[:, None], mean=mean, kernel=kernel,
                         seed=comp, restarts=restarts,
                         probe_mm=_probe if probe_input else None)


@st.cache_resource(show_spinner=False, max_entries=128)
def gp_predict(args, mean, kernel, comp, grid_key, _comp, _grid, _probe):
    m, sd = predict_grid(_comp, _grid, probe_mm=_probe if _comp.probe_input else None)
    return np.asarray(m, float)[:, 0], np.asarray(sd, float)[:, 0]


@st.cache_data(show_spinner=False, max_entries=32)
def plane_grid(args, position, _r, _kinematic_um):
    """The chosen placement's plate-plane grid with the kinematic error on it."""
    return placement_plane_grid(_r, position, _kinematic_um)


def _probe_names(comp, obs) -> list:
    """Names of the styli in the order of the GP's noise groups (sorted offsets)."""
    if not comp.noise_per_probe or comp.probe_offsets_mm is None:
        return []
    names = []
    for off in comp.probe_offsets_mm:
        hit = np.flatnonzero(np.all(np.isclose(obs.p_mm, off), axis=1))
        names.append(str(obs.probes[obs.probe[hit[0]]]) if hit.size else "?")
    return names


def _fmt_lengths(v) -> str:
    """Length scale(s) in mm to 4 significant digits (one per input for ARD)."""
    vals = np.atleast_1d(np.asarray(v if v is not None else np.nan, float))
    return " / ".join(f"{x:.4g}" for x in vals)


def fit_gp_all(args, target_name, mean, kernel, restarts, probe_input, points, target, probe):
    """The three component GPs with a progress bar."""
    bar = st.progress(0.0, text="Fitting the GP (hyperparameters by marginal likelihood)…")
    comps = []
    for c_ in range(3):
        bar.progress(c_ / 3, text=f"Fitting the GP for e{'xyz'[c_]} ({c_ + 1}/3)…")
        comps.append(fit_gp_component(args, target_name, mean, kernel, restarts, c_,
                                      probe_input, points, target[:, c_], probe))
    bar.empty()
    return comps


def predict_all(args, mean, kernel, grid_key, comps, grid, probe):
    out = [gp_predict(args, mean, kernel, c_, grid_key, comps[c_], grid, probe)
           for c_ in range(3)]
    return np.column_stack([o[0] for o in out]), np.column_stack([o[1] for o in out])


args = cached.fit_key()
pts, err, meta = measured_errors(args, ds, cached.instrument_data(args))
u_res = kinematic_residual_u(args, r)
# rows of the kinematic fit and the rigid fit are the same selection, same order
pred_kin = err + r.residuals_um

c1, c2, c3, c4, c5 = st.columns([3, 2, 2, 2, 1])
# the choices are in the URL (bind): a reload keeps them (issue 27)
MEANS = {"zero": "zero", "thesis_quadratic": "quadratic (eq. 5.11)",
         "kinematic": "kinematic model"}
mean_choice = c1.radio("GP mean", list(MEANS), horizontal=True, key="w_gp_mean", bind="query-params",
                       format_func=MEANS.get)
kernel = c2.radio("Kernel", ["se_iso", "se_ard"], horizontal=True, key="w_gp_kernel", bind="query-params",
                  format_func={"se_iso": "SE isotropic", "se_ard": "SE ARD"}.get)
position = c3.selectbox("Plate position (surface plane)", r.problem.obs.positions,
                        key="w_gp_position", bind="query-params")
comp = c4.radio("Component", ["x", "y", "z"], horizontal=True, key="w_gp_comp", bind="query-params")
restarts = int(c5.number_input("Restarts", 0, 10, 1, key="w_gp_restarts", bind="query-params",
                               help="Random restarts of the hyperparameter optimisation per "
                                    "component (more: slower, less risk of a local optimum)."))
a = "xyz".index(comp)
several_probes = len(np.unique(r.problem.obs.p_mm, axis=0)) > 1
probe_input = st.checkbox(
    "Probe offset as input (ram position and stylus offset, one noise level per stylus)",
    value=several_probes, key="w_gp_probe", bind="query-params", disabled=not several_probes,
    help="With several styli, a stylus-dependent error (an angular error seen through the "
         "offset, a probe offset error) is part of the GP rather than of its noise, and each "
         "stylus gets its own repeatability. Off: the inputs are the tip coordinates only."
         + ("" if several_probes else " These data carry one stylus: nothing to add."))
probe_input = bool(probe_input and several_probes)

obs = r.problem.obs
plane = plane_grid(args, position, r, pred_kin)
uu, vv, n, sel = plane.u_mm, plane.v_mm, len(plane.u_mm), plane.selected
grid_m, e_kin_grid, pk, probe_k = plane.machine_mm, plane.kinematic_um, plane.probe_mm, plane.probe
pts_plate = plane.balls_plate_mm

# one symmetric colour range for the model and GP mean maps: compare them by colour
zlim = float(np.nanmax(np.abs(np.concatenate([e_kin_grid[:, a], err[sel, a]])))) or 1.0
cols = st.columns(3)
with cols[0], calls.guarded("Kinematic surface"):
    widgets.show(widgets.beside_map(A.fig_surface_grid(uu, vv, e_kin_grid[:, a].reshape(n, n),
                                      title=f"Kinematic model e{comp} (µm)", unit="µm",
                                      points=pts_plate, xlabel="plate u (mm)",
                                      ylabel="plate v (mm)", zrange=(-zlim, zlim))),
               chart_key="gp_kin_surface", width_px=520, width="stretch")
gp_mean_obs = loo = loo_sd = None
coverage = {}
if not s.get("gp_on"):
    with cols[1]:
        st.info("Fitting the GP optimises its hyperparameters by marginal likelihood for each "
                "error component; it can take several seconds. Once fitted, it refits "
                "whenever an input changes (changing an input again cancels the fit).")
        if st.button("Fit the GP", key="fit_gp", type="primary"):
            s["gp_on"] = True
            st.rerun()
if s.get("gp_on"):
    with calls.guarded("Gaussian process"):
        target = err - pred_kin if mean_choice == "kinematic" else err
        gmean = "zero" if mean_choice == "kinematic" else mean_choice
        target_name = "kinematic residuals" if mean_choice == "kinematic" else "measured"
        comps = fit_gp_all(args, target_name, gmean, kernel, restarts, probe_input, pts, target,
                           obs.p_mm)
        # a degenerate optimum (issue 11): said so, with the next-best optimum offered
        degen = [(c_, cp.results[0]) for c_, cp in zip("xyz", comps, strict=True)
                 if cp.results[0].degenerate]
        use_alt = False
        if degen:
            st.warning("**Degenerate GP fit** for "
                       + "; ".join(f"e{c_}: {g.degenerate_reason}" for c_, g in degen)
                       + ". The likelihood's best optimum is not a usable error model; "
                       "the next-best optimum is "
                       + "; ".join(f"e{c_}: length scale {_fmt_lengths(g.alternative.length_scale_mm)} mm, "
                                   f"log marginal likelihood lower by "
                                   f"{g.log_marginal_likelihood - g.alternative.log_marginal_likelihood:.2f}"
                                   + (f" (itself degenerate: {g.alternative.degenerate_reason})"
                                      if g.alternative.degenerate else "")
                                   for c_, g in degen if g.alternative is not None) + ".")
            use_alt = st.checkbox("Use the next-best optimum for the degenerate component(s)",
                                  key="w_gp_use_alt")
        if use_alt:
            comps = [replace(cp, results=(cp.results[0].alternative,))
                     if cp.results[0].degenerate and cp.results[0].alternative is not None
                     else cp for cp in comps]
        gkey = (mean_choice, kernel, restarts, probe_input, use_alt)
        gm, gsd = predict_all(args, gkey, kernel, f"{position}-{n}", comps, grid_m, pk)
        om, osd = predict_all(args, gkey, kernel, "obs", comps, pts, obs.p_mm)
        # leave-one-out predictions (R&W eq. 5.12): each ball predicted without itself
        loo = np.column_stack([c_.results[0].loo_mean_um for c_ in comps])
        loo_sd = np.column_stack([c_.results[0].loo_sd_um for c_ in comps])
        if mean_choice == "kinematic":
            gm = gm + e_kin_grid
            om = om + pred_kin
            loo = loo + pred_kin
        gp_mean_obs = om
        with cols[1]:
            widgets.show(widgets.beside_map(A.fig_surface_grid(
                uu, vv, gm[:, a].reshape(n, n), title=f"GP mean e{comp} (µm)", unit="µm",
                points=pts_plate, xlabel="plate u (mm)", ylabel="plate v (mm)",
                zrange=(-zlim, zlim))), chart_key="gp_mean_surface", width_px=520,
                width="stretch")
        with cols[2]:
            widgets.show(widgets.beside_map(A.fig_surface_grid(
                uu, vv, gsd[:, a].reshape(n, n), title=f"GP standard deviation e{comp} (µm)",
                unit="µm", points=pts_plate, colorscale="Viridis", xlabel="plate u (mm)",
                ylabel="plate v (mm)")), chart_key="gp_sd_surface", width_px=520,
                width="stretch")
        coverage = {"xyz"[i]: 100 * c_.results[0].loo_coverage(0.95)
                    for i, c_ in enumerate(comps)}
        probe_names = _probe_names(comps[0], obs)
        hyp = pd.DataFrame([{
            "component": "xyz"[i],
            "length scale (mm)": _fmt_lengths(g.length_scale_mm),
            "signal sd (µm)": g.signal_sd_um,
            "noise sd (µm)": g.noise_sd_um,
            "noise sd per stylus (µm)": ", ".join(
                f"{p}: {v:.2f}" for p, v in zip(probe_names, g.noise_sd_by_group_um,
                                                  strict=True)) if probe_names else "—",
            "log marginal likelihood": g.log_marginal_likelihood,
            "LOO RMS (µm)": g.loo_rms_um,
            "LOO 95 % coverage (%)": coverage["xyz"[i]],
            "status": g.status if not (use_alt and g.message.startswith("next-best"))
            else "next-best optimum"}
            for i, g in enumerate(c_.results[0] for c_ in comps)])
        st.markdown("**Fitted hyperparameters** (one GP per error component; inputs: "
                    + ("ram position (one length scale, or one per axis for ARD) and stylus "
                       "offset (one length scale)" if probe_input else
                       "tip coordinates") + ")")
        widgets.dataframe(hyp, hide_index=True, key="gp_hyper", column_config={
            c_: st.column_config.NumberColumn(format="%.3f") for c_ in
            ("signal sd (µm)", "noise sd (µm)", "log marginal likelihood", "LOO RMS (µm)")}
            | {"LOO 95 % coverage (%)": st.column_config.NumberColumn(format="%.1f")})
        # a length scale far beyond the data is legitimate but reads like a bug: say what it is
        span_mm = float(np.max(np.ptp(pts, axis=0)))
        very_long = [f"e{'xyz'[i]} ({_fmt_lengths(c_.results[0].length_scale_mm)} mm)"
                     for i, c_ in enumerate(comps)
                     if np.nanmax(np.atleast_1d(np.asarray(
                         c_.results[0].length_scale_mm, float))) > 10 * span_mm]
        if very_long:
            st.caption(f"Length scale more than ten times the measured volume ({span_mm:.0f} mm "
                       "across) for " + ", ".join(very_long) + ": along that input the GP "
                       "is a nearly straight trend over the whole volume (the data show no "
                       "curvature it could follow); this is what the marginal likelihood "
                       "prefers, not a failed fit.")
        cov_cols = st.columns(3)
        for col, (c_, v) in zip(cov_cols, coverage.items(), strict=True):
            col.metric(f"e{c_}: LOO 95 % coverage", f"{v:.1f} %",
                       help="Share of the points inside the 95 % interval of their "
                            "leave-one-out prediction (each predicted from all the others, "
                            "noise included). 95 % when the GP's uncertainty is right.")
        n_pts = len(pts)
        tol = 2.0
        off = {c_: v for c_, v in coverage.items() if abs(v - 95) > tol}
        if off:
            st.warning(
                "Leave-one-out coverage outside 95 ± 2 % for "
                + ", ".join(f"e{c_} ({v:.1f} %)" for c_, v in off.items())
                + f" ({n_pts} points, one point = {100 / n_pts:.1f} %): the GP's intervals "
                + ("are too narrow" if all(v < 95 for v in off.values()) else
                   "are too wide" if all(v > 95 for v in off.values()) else
                   "are off") + " for points it has not seen. Why, from the numbers of each "
                "component:")
            loo_target = target if mean_choice == "kinematic" else err
            for i, (c_, v) in enumerate(coverage.items()):
                if c_ not in off:
                    continue
                g = comps[i].results[0]
                z_loo = ((np.asarray(g.loo_mean_um, float) - loo_target[:, i])
                         / np.asarray(g.loo_sd_um, float))
                why = coverage_reasons(
                    v, z_loo, meta, g.noise_sd_by_group_um if probe_names else None,
                    probe_names, several_probes, bool(g.degenerate))
                st.caption(f"**Why e{c_} covers {v:.1f} % rather than 95 ± 2 %:** "
                           + " ".join(w[:1].upper() + w[1:] for w in why))
        else:
            st.caption(f"Leave-one-out 95 % coverage within 95 ± 2 % in every component "
                       f"({n_pts} points, one point = {100 / n_pts:.1f} %): the GP's "
                       "uncertainty is consistent with the points it has not seen.")
st.caption("Plate plane of the chosen position (plate u and v in mm); × marks the measured "
           "ball centres. Errors in µm, in the rigid-aligned "
           "sense (the placement of the plate absorbs translations and rotations). "
           + (f"The GP's inputs are the ram position and the stylus offset, so a "
              "stylus-dependent error (rotations seen through the probe offset, a probe "
              "offset error) is part of the GP, and each stylus has its own noise level; "
              f"the surfaces are for the stylus of {position} (probe {probe_k})."
              if probe_input else
              "The GP's inputs are the tip coordinates only: two styli measuring the same "
              "ball get the same prediction, so a stylus-dependent error (rotations seen "
              "through the probe offset, a probe offset error) shows up in its noise level; "
              "the kinematic model, which knows each stylus's offset, separates it."))

st.subheader("Kinematic vs GP vs measurement (thesis chapter 7)")
# the kinematic z-scores are σ-based: say whether σ describes the scatter
widgets.misfit_banner(r)
ch7 = compare_models(r, err, pred_kin, u_res, comp, points_mm=pts, meta=meta,
                     gp_mean_um=gp_mean_obs, gp_loo_mean_um=loo, gp_loo_sd_um=loo_sd)
rows = ch7.table
sigma = ch7.sigma_um
st.caption(f"All positions, component {comp}:")
mc = st.columns(len(ch7.summary))
for c_, f in zip(mc, ch7.summary, strict=True):
    c_.metric(f.label, f"{f.value:.3f}", help=f.meaning)
only = st.checkbox("Table: only the chosen position", value=True, key="w_gp_only_pos", bind="query-params")
widgets.dataframe(rows[rows["position"] == position] if only else rows, hide_index=True,
             key="ch7_table",
             column_config={c_: st.column_config.NumberColumn(format="%.3f")
                            for c_ in rows.columns if c_.endswith(("_um", "_z"))} | {
                 "kin_z": st.column_config.NumberColumn(
                     "kin_z (residual sd)", format="%.2f",
                     help="(kinematic − measured) / σ√(1 − h_ii): the difference at a ball "
                          "the model was fitted to is its residual."),
                 "gp_loo_z": st.column_config.NumberColumn(
                     "gp_z (leave-one-out)", format="%.2f",
                     help="(GP leave-one-out prediction − measured) / its leave-one-out sd, "
                          "noise included: each ball predicted from all the others."),
                 "thesis_pct_kin": st.column_config.NumberColumn(
                     "thesis eq. 7.1 % (kinematic)", format="%.5f"),
                 "thesis_pct_gp": st.column_config.NumberColumn(
                     "thesis eq. 7.1 % (GP)", format="%.5f")})
st.caption(
    f"Component {comp}. Differences are in µm and in units of their standard uncertainty. "
    "The kinematic model was fitted to these very balls, so its difference from the "
    f"measurement is the fit's residual: *kin_z* divides it by the residual's sd "
    f"σ√(1 − h_ii) (σ = {sigma:g} µm; h_ii the ball's leverage), not by √(u_model² + σ²), "
    "which treats model and measurement as independent and makes z too small. The GP's "
    "in-sample difference has the same problem, so its z (*gp_z (leave-one-out)*) "
    "compares each ball with the GP's prediction from all the other balls, divided by "
    "that prediction's sd (noise included). |z| ≲ 2 is agreement; an RMS z near 1 means "
    "the stated uncertainties match the scatter (for the kinematic model, only when the "
    "fit passes its χ² test). The "
    "columns labelled *thesis eq. 7.1 %* reproduce the thesis's 'percentage error' only for "
    "comparison: it divides a micrometre difference by the ball's coordinate (≈ 0.5 m), so "
    "any model scores a few thousandths of a percent; it is not a measure of model quality. "
    "The GP columns evaluate it at its own training points, which flatters it; the "
    "leave-one-out columns predict each ball from all the others, the fair comparison "
    "with a measurement the model has not seen.")
