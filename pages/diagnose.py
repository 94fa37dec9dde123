"""Compare and diagnose: where the model fails, which effect is missing, add it, watch."""

import json
from contextlib import nullcontext

import numpy as np
import pandas as pd
import streamlit as st

from cmm_core import analysis as A
from cmm_core.model import PERIODIC, catalogue_entry, parse_spec
from cmm_core.plan import (
    PSEUDO,
    instrument_candidates,
    measurement_candidates,
    open_pairs,
    plan_file,
    propose,
    restrict,
    simulate_outcomes,
)
from cmm_core.units import p_text
from pages.ui import cached, calls, state, widgets

# proposals shown with their buttons (the rest in the table below them); a comment: a
# page script's bare string is written onto the page (Streamlit's "magic")
NEXT_TOP = 3


# --- measure next: thin cached wrappers into cmm_core.plan.proposals (issue 29) ---------
# cmm_core.plan is imported inside them: only a user who opens "Measure next" pays for it


def _selected(key: cached.FitKey, ds):
    """The data set as the fit selects it (positions, probes, exclusions)."""

    kw = key.fit_kwargs()
    return restrict(ds, positions=kw["positions"], probes=kw["probes"], exclude=kw["exclude"])


def _settings(key: cached.FitKey) -> dict:
    kw = key.fit_kwargs()
    return {"baseline": key.spec, "order": kw["order"], "plate": kw["plate"],
            "sigma_um": kw["sigma_um"]}


@st.cache_data(show_spinner="Scoring candidate measurements…", max_entries=16)
def cached_proposals(key: cached.FitKey, rivals: tuple, _ds, instruments: bool = False):
    """``plan.propose`` of the default candidate set for the two rivals (``Proposals``);
    ``instruments``: the instrument runs too (``plan.instrument_candidates``)."""

    data = _selected(key, _ds)
    cands = measurement_candidates(data) + (instrument_candidates(data) if instruments
                                            else [])
    return propose(data, rivals, cands=cands, **_settings(key))


@st.cache_data(show_spinner="Simulating the proposal with each rival as the truth…",
               max_entries=16)
def cached_outcomes(key: cached.FitKey, rivals: tuple, name: str, seed: int, _ds,
                    _proposal) -> dict:
    """``plan.simulate_outcomes`` of proposal ``name`` (the rivals' proposal of ``key``):
    ``{truth: {verdict, aliases, separated, message}}``."""

    outs = simulate_outcomes(_selected(key, _ds), _proposal, seed=seed, **_settings(key))
    return {t: {"verdict": o.verdict, "aliases": list(o.aliases), "separated": o.separated,
                "message": o.message} for t, o in outs.items()}


@st.cache_data(show_spinner=False, max_entries=16)
def cached_plan_text(key: cached.FitKey, rivals: tuple, name: str, _ds, _proposal) -> str:
    """The proposal as a ``plan`` JSON document (``plan.plan_file``)."""

    return json.dumps(plan_file(_selected(key, _ds), _proposal, baseline=key.spec,
                                order=key.order, noise_um=key.sigma_um), indent=1)


def _pairs(cands: list, holdout: list | None) -> list:
    """The rivals the diagnosis leaves open, by the core's one rule (``plan.open_pairs``,
    as the ``next`` command's default): the page's rows (``Candidate.to_dict`` with the
    aliases joined into one string) and the diagnosis's leave-one-placement-out checks
    (``Diagnosis.to_dict``'s ``holdout``; none: no placement-scale pair)."""

    return open_pairs({"candidates": [
        {**c, "aliases": [a for a in str(c["aliases"] or "").split(", ") if a]}
        for c in cands], "holdout": list(holdout or [])})


def _rivals_words(rivals) -> str:
    """The rivals in words: "A against B", "A against B and C" (an alias set)."""
    rest = [str(r) for r in rivals[1:]]
    return f"{rivals[0]} against " + (rest[0] if len(rest) == 1 else
                                      f"{', '.join(rest[:-1])} and {rest[-1]}")


def _outcome_words(truth: str, other: str, o: dict) -> str:
    if o["separated"]:
        return (f"with **{truth}** as the truth the diagnosis names `{o['verdict']}`, "
                f"{other} no longer its alias: **separated**")
    named = f"names `{o['verdict']}`" if o["verdict"] else "names no effect"
    still = f", still aliased with {', '.join(o['aliases'])}" if o["aliases"] else ""
    return f"with **{truth}** as the truth the diagnosis {named}{still}: **not separated**"


def measure_next(ds, fkey: cached.FitKey, cands: list, holdout: list | None = None) -> None:
    """The proposals beside the rivals of the current verdict: the top ones in words,
    each with "Simulate it" and "Use as the plan"; the others in a table. ``holdout``:
    the diagnosis's leave-one-placement-out checks (``Diagnosis.to_dict``)."""

    s = st.session_state
    pairs = _pairs(cands, holdout)
    if not pairs:
        st.info("The diagnosis leaves no pair of rival effects open (no alias, no "
                "significant runner-up of another function): nothing to decide.")
        return
    st.caption("Rivals of the current verdict: its aliases and its runner-up. Each candidate "
               "measurement (the plate shifted, moved, rotated, stood up, another stylus) "
               "is scored by how surely the diagnosis would then tell the two apart, each "
               "rival in turn the truth at its size fitted here (docs/proposals.md).")
    if fkey.instruments:
        st.caption("The instrument files fitted with the plate are left out of the proposals.")
    pair = st.selectbox("Rivals to tell apart", pairs, key="w_next_pair",
                        format_func=_rivals_words)
    pair = tuple(pair)
    tools = st.checkbox("Also instrument runs (laser along X, Y, Z; step gauge along X, Y; "
                        "ball bar in XY)", key="w_next_instruments",
                        help="Scored and simulated as the plate's candidates; a plan file "
                             "cannot hold them (docs/proposals.md).")
    pr = calls.safe(cached_proposals, fkey, pair, ds, bool(tools), what="Measure next")
    if pr is None:
        return
    if not pr.decided:
        # the conclusion before the proposals: listed first, the best of them would read
        # as a recommendation; the core's message says none decides and which wider
        # family (instrument runs, ...) was not searched and might
        st.warning(pr.message)
        if not pr.ranked:
            return
    now = min(pr.current.values())
    st.markdown(f"The current data decide {_rivals_words([f'**{r}**' for r in pair])} "
                f"with {100 * now:.0f} % power (target {100 * pr.target:.0f} %).")
    for i, p in enumerate(pr.ranked[:NEXT_TOP]):
        name = p.candidate.name
        with st.container(border=True):
            st.markdown(f"**{i + 1}.** {p.outcome[0].upper() + p.outcome[1:]}.")
            b1, b2 = st.columns(2)
            plate = not p.candidate.instrument
            # a placement's own scale is outside the catalogue (the virtual CMM cannot
            # measure it as the truth); against the baseline the power is the outcome
            can_sim = not set(pair) & PSEUDO
            if b1.button("Simulate it", key=f"next_sim_{name}", disabled=not can_sim,
                         help="Simulate this measurement with each rival in turn as the "
                              "truth (its fit on these data; noise σ, an instrument its own "
                              "uncertainty), append it to the data and run the diagnosis." + ("" if can_sim else
                              " Not for a placement's own scale (outside the catalogue, "
                              "the virtual CMM cannot simulate it) nor against the baseline "
                              "(the power above is the outcome).")):
                s["next_sim"] = (fkey, pair, name)
            if b2.button("Use as the plan", key=f"next_plan_{name}", disabled=not plate,
                         help="Open this measurement on the Plan page as a plan file: "
                              "the current placements, and with it (a repeat: its balls "
                              "measured again at the end)." + ("" if plate else " Not for "
                              "an instrument run, which a plan file cannot hold.")):
                text = calls.safe(cached_plan_text, fkey, pair, name, ds, p,
                                  what="Plan file")
                if text is not None:
                    s["plan_proposal"] = {"data": fkey.data, "name": name,
                                          "outcome": p.outcome, "text": text, "fresh": True}
                    st.switch_page("pages/plan.py")
            if s.get("next_sim") == (fkey, pair, name):
                outs = calls.safe(cached_outcomes, fkey, pair, name, 0, ds, p,
                                  what="Simulating the proposal")
                if outs is not None:
                    st.markdown("Simulated (seed 0): " + "; ".join(
                        _outcome_words(t, " nor ".join(o_ for o_ in pair if o_ != t),
                                       outs[t]) for t in pair) + ".")
                    if all(o["separated"] for o in outs.values()):
                        st.success("The rivals separate: measured, this tells them apart.")
                    else:
                        st.warning("The rivals do not both separate in this simulation "
                                   "(one seed; the power above is the rate over many).")
    widgets.dataframe(pd.DataFrame([{
        "measurement": p.candidate.description, "time (min)": p.candidate.time_min,
        "Δχ² (min)": p.per_minute * p.candidate.time_min, "power": p.power_min}
        for p in pr.ranked]), hide_index=True, key="next_table",
        column_config={"Δχ² (min)": st.column_config.NumberColumn(format="%.1f"),
                       "power": st.column_config.NumberColumn(format="%.2f"),
                       "time (min)": st.column_config.NumberColumn(format="%.0f")})
    if pr.skipped:
        st.caption("Not scored: " + "; ".join(f"{k}: {v}" for k, v in pr.skipped.items()))
st.title("Compare and diagnose")
st.caption("The model against the measurements: where it fails, which physical effect the "
           "residuals point to, and what adding it does to RMS, χ²/dof, BIC and the GP "
           "discrepancy.")
widgets.flash()
ds, r = cached.require_fit()
s = st.session_state
fkey = cached.fit_key()  # what decides the fit: the key of its cached figures

c = st.columns(4)
# the model as the user wrote it, wrapped at its commas (a metric would cut it)
_spec, _spec_help = widgets.spec_markdown(s["spec"])
c[0].markdown(f"Model  \n{_spec}", help=_spec_help)
c[1].metric("RMS residual", f"{r.rms_um:.3f} µm")
# one χ²/dof is the headline: the one the χ² test decides on (with a fixed certificate
# it counts the certificate's uncertainty; the fit's own value is named in the help)
c[2].metric("χ²/dof (tested)", f"{r.chi2_test_dof:.2f}",
            help=("The statistic the χ² test decides on." + (
                f" The fit's own χ²/dof, {r.chi2_dof:.2f}, leaves out the certificate's "
                "uncertainty that the test counts with a fixed certificate."
                if r.test_counts_certificate else "")))
c[3].metric("BIC", f"{r.bic:.1f}")
# reversal and certificate uncertainties below are σ-based
widgets.misfit_banner(r)

st.subheader("Where the model fails")
# lazy tabs: a hidden tab's figure (the 3-D map's WebGL scene above all) is neither built
# nor drawn, so the page and every rerun of it (Add, Undo) draw one figure here (issue 27)
t_pat, t_map, t_tab, t_time = st.tabs(["Residual pattern", "Residual map (3D)",
                                       "Per position and probe", "Against time and direction"],
                                      key="w_diag_tab", on_change="rerun",
                                      bind="query-params")
with t_pat, calls.guarded("Residual pattern"):
    if t_pat.open:
        widgets.plot("pattern", fkey, A.fig_pattern, r.table, r.residuals_um,
                   "Residuals per observation (µm)", chart_key="diag_resid")
with t_map, calls.guarded("Residual map"):
    comp = st.radio("Component", ["norm", "x", "y", "z"], horizontal=True, key="w_map_comp")
    if t_map.open:
        st.plotly_chart(cached.figure("resmap", (fkey, comp), A.fig_residual_map, r, comp),
                        key="diag_map")
with t_tab, calls.guarded("Residual table"):
    by = st.radio("Group by", ["position", "probe", "ball"], horizontal=True,
                  key="w_breakdown_by")
    widgets.dataframe(A.breakdown(r, by), hide_index=True, key="diag_breakdown")
    st.caption("RMS per axis in µm; χ² against σ and its share of the total.")
    if ds.certificate is not None:
        st.markdown("**Each position against the certificate** (own scale and "
                    "out-of-plane bowl)")
        widgets.dataframe(A.position_trends(ds, exclude=fkey.exclusions),
                     hide_index=True, key="diag_trends")
with t_time, calls.guarded("Residuals against time"):
    rf = r.residuals_frame()
    timed = "time_min" in rf and rf["time_min"].notna().all()
    if timed and t_time.open:
        widgets.show(A.fig_residuals_time(rf), chart_key="diag_time")
    elif not timed:
        st.info("No time_min column: the measurement order is the row order of the files, "
                "and drift is scored over that order at one minute per row: its µm/h are "
                "µm per 60 rows, not per hour of clock time.")
    st.markdown("**By approach direction**: mean residual of each axis over the balls "
                "reached moving + and moving − along it (a difference is a reversal error, "
                "the `backlash` effect)")
    widgets.dataframe(A.approach_split(r), hide_index=True, key="diag_approach",
                column_config={c_: st.column_config.NumberColumn(format="%.3f") for c_ in
                               ("mean_plus_um", "mean_minus_um", "reversal_um",
                                "u_reversal_um")})

st.subheader("Which effect is missing?")
pending = cached.pending_outliers(ds)
# the flagged outliers still in the fit: said here, unless the diagnosis's headline says it
# (its verdict is that they hold the misfit), so one condition gets one message and button
outlier_slot = st.container()
cols = st.columns([1, 1, 4])
if cols[0].button("Run the diagnosis", key="run_diagnosis", type="primary"):
    s["diag_on"] = True
if cols[1].button("Hide", key="hide_diagnosis"):
    s["diag_on"] = False

base, cands, conclusion, info = (cached.run_diagnosis(show_progress=True) if s["diag_on"]
                                 else (None, None, "", {}))
head = info.get("headline")  # the core's headline (Diagnosis.headline), drawn as it is
if pending and not (head and head["verdict"] == "flagged_outliers"):
    with outlier_slot:
        w1, w2 = st.columns([4, 1])
        w1.warning(f"{len(pending)} flagged outlier(s) are still in the fit: one blunder of "
                   "tens of µm can hide a real effect or pose as one. Exclude them first "
                   "(the Data page lists them).")
        w2.button("Exclude the flagged outliers", key="diag_exclude_outliers",
                  on_click=state.set_exclusions, args=(pending, True))

if s["diag_on"]:
    if cands is None:
        st.stop()
    cert = info.get("certificate")
    if cert and cert["suspect"]:
        with st.container(border=True):
            st.warning(cert["message"])
            if cert["entries"]:
                widgets.dataframe(pd.DataFrame(cert["entries"]), hide_index=True, key="cert_entries",
                            column_config={"deviation_um": st.column_config.NumberColumn(
                                "self-calibrated − certificate (µm)", format="%.2f"),
                                "u_um": st.column_config.NumberColumn("u (µm)", format="%.2f"),
                                "z": st.column_config.NumberColumn("z", format="%.1f")})
            fixes = pd.DataFrame([{"plate geometry": k, "χ²/dof": v["chi2_dof"],
                                   "RMS (µm)": v["rms_um"],
                                   "χ² test": "fails" if v["fails_chi2_test"] else "passes"}
                                  for k, v in cert["fixes"].items()])
            widgets.dataframe(fixes, hide_index=True, key="cert_fixes",
                        column_config={"χ²/dof": st.column_config.NumberColumn(format="%.2f"),
                                       "RMS (µm)": st.column_config.NumberColumn(format="%.3f")})
            b1, b2 = st.columns(2)
            b1.button("Use the certificate as a prior", key="cert_prior",
                      on_click=state.set_plate, args=("prior",))
            b2.button("Self-calibrate the plate (free)", key="cert_free",
                      on_click=state.set_plate, args=("free",))
    # the verdict in one message, with the one button its action needs
    if head["verdict"] == "flagged_outliers":
        b1, b2 = st.columns([4, 1])
        widgets.headline(head, b1)
        b2.button("Exclude the flagged outliers", key="diag_exclude_blunders",
                  on_click=state.set_exclusions, args=(pending, True), type="primary",
                  disabled=not pending)
    else:
        widgets.headline(head)
    if head["verdict"] == "sigma_too_small":
        sigma = info["sigma_check"]
        st.button(f"Refit with σ = {sigma['value_um']:.3g} µm", key="adopt_sigma",
                  on_click=state.set_sigma, args=(sigma["value_um"],), type="primary")
    if cands:
        st.caption(conclusion)
        cols_shown = ["effect", "title", "rms_um", "chi2_dof", "delta_chi2", "n_params",
                      "delta_bic", "p_value", "significant", "confirmed", "aliases"]
        table = pd.DataFrame([{k: c_.get(k) for k in cols_shown} for c_ in cands])
        # as the text says it (p < 1e-16, never 0): a number format shows an underflowed
        # p as 0; ΔBIC beside it sorts the candidates by their evidence
        table["p_value"] = [p_text(np.nan if p is None else p).removeprefix("p ")
                            .removeprefix("= ") for p in table["p_value"]]
        widgets.dataframe(table, hide_index=True, key="diag_table",
                     column_config={"effect": "Effect", "title": "What it is",
                                    "n_params": st.column_config.NumberColumn("Parameters"),
                                    "significant": "Significant", "confirmed": st.column_config
                                    .CheckboxColumn("Refit", help="numbers from a full refit"),
                                    "aliases": "Aliases","rms_um": st.column_config.NumberColumn("RMS (µm)",
                                                                            format="%.3f"),
                                    "chi2_dof": st.column_config.NumberColumn("χ²/dof",
                                                                              format="%.2f"),
                                    "delta_bic": st.column_config.NumberColumn("ΔBIC",
                                                                               format="%.1f"),
                                    "delta_chi2": st.column_config.NumberColumn(
                                        "Δχ²", format="%.1f"),
                                    "p_value": st.column_config.TextColumn("p")})
        n_show = (st.slider("Candidates to show in detail", 1, min(10, len(cands)),
                            min(3, len(cands)), key="w_n_show") if len(cands) > 1 else 1)
        for i, c_ in enumerate(cands[:n_show]):
            with st.container(border=True):
                h1, h2 = st.columns([5, 1])
                h1.markdown(f"**{i + 1}. {c_['title']}** (`{c_['effect']}`): RMS "
                            f"{c_['rms_um']:.3f} µm, χ²/dof {c_['chi2_dof']:.2f}, ΔBIC "
                            f"{c_['delta_bic']:.1f}, {p_text(c_['p_value'])}"
                            + (" — significant" if c_["significant"] else ""))
                # an effect the data cannot determine on top of this model adds only
                # undetermined parameters: nothing to add
                # one button, worded by the candidate's standing: a candidate the data do
                # not call for can still be tried, but the label says so
                h2.button("Add this effect" if c_["significant"] else "Add this effect anyway",
                          key=f"add_{c_['effect']}",
                          on_click=state.apply_change, args=(c_["effect"],), type="primary"
                          if c_["significant"] else "secondary",
                          disabled=c_["n_params"] == 0,
                          help="The data cannot determine it on top of this model."
                          if c_["n_params"] == 0 else None if c_["significant"] else
                          "Not significant at its level: the data do not call for it; "
                          "adding it costs degrees of freedom (try it, and Undo if the "
                          "error does not fall).")
                if c_["would_leave_undetermined"]:
                    st.warning(f"Adding it as is would leave "
                               f"{len(c_['would_leave_undetermined'])} parameter combination(s) "
                               "undetermined (U1-U3 then cannot be evaluated). "
                               + " ".join(dict.fromkeys(c_["would_leave_undetermined"][:3]))
                               + " Remove one of the functions named there, add a placement "
                               "or stylus that exercises them, or use a lower order.")
                if c_["holdout"]:
                    st.caption(f"Leave-one-placement-out check: {c_['holdout']}.")
                st.write(c_["explanation"][:1].upper() + c_["explanation"][1:])
                st.caption(f"This data set would see it above: {c_['detectable_above']} "
                           "(80 % probability at the test's level). A smaller effect may be "
                           "present and go unseen: a longer stylus, more placements or "
                           "repeats lower these limits.")
                aliases = c_["aliases"]
                if aliases:
                    st.caption(f"Aliases with this data: {aliases}. To separate them: "
                               f"{c_['separate_by']}")
                else:
                    st.caption(f"To confirm it: {c_['separate_by']}")
                # open for the named effect (the first when none is named), and fresh for
                # each diagnosis: a toggle left on for another candidate no longer carries
                # over (issue 27)
                opened = c_["is_verdict"] or (i == 0 and not any(
                    x["is_verdict"] for x in cands))
                if st.toggle("Show residuals beside its signature", value=opened,
                             key=f"w_sig_{hash(fkey) & 0xFFFFFFFF:x}_{c_['effect']}"):
                    f1, f2 = st.columns(2)
                    with f1:
                        widgets.plot("pattern_small", fkey, A.fig_pattern, base.table,
                                   base.residuals_um, "Residual pattern (µm)", 300,
                                   chart_key=f"sig_res_{c_['effect']}", width_px=640)
                    with f2:
                        widgets.plot("signature", (fkey, c_["effect"]), A.fig_pattern,
                                   base.table, c_["signature_um"],
                                   f"Signature of {c_['effect']} (µm)", 300,
                                   chart_key=f"sig_{c_['effect']}", width_px=640)
                    sv, rv = np.ravel(c_["signature_um"]), np.ravel(base.residuals_um)
                    den = float(np.linalg.norm(sv) * np.linalg.norm(rv))
                    corr = float(sv @ rv) / den if den > 0 else 0.0
                    widgets.plot("sig_scatter", (fkey, c_["effect"]), A.fig_signature_scatter,
                               base.residuals_um, c_["signature_um"],
                               "Residual against the signature: along the dashed line where "
                               "the effect explains it", 280, chart_key=f"sig_sc_{c_['effect']}")
                    st.caption(f"Correlation of residual and signature r = {corr:.2f}: the "
                               f"effect accounts for {100 * corr**2:.0f} % of the residual "
                               "sum of squares; the rest is what remains after adding it.")
        # the measurement that would settle what these data cannot (issue 29); computed
        # only while open, as the tabs above
        with st.expander("Measure next: the measurement that would tell the rivals apart",
                         key="w_diag_next", on_change="rerun") as nxt, \
                calls.guarded("Measure next"):
            if nxt.open:
                measure_next(ds, fkey, cands, info.get("holdout"))

st.subheader("History")
st.checkbox("Also compute the GP discrepancy amplitude of each step (a GP over the "
            "residuals with the model's own design matrix as basis; about a second per "
            "step on the thesis data)", key="hist_gp")
with st.spinner("Fitting the GP discrepancy…") if s.get("hist_gp") else nullcontext():
    hist = cached.history_rows()
with calls.guarded("History chart"):
    widgets.plot("history", tuple(tuple(sorted(h.items())) for h in hist), A.fig_history, hist,
               chart_key="diag_history")
c1, c2 = st.columns([3, 1])
with c1:
    # the model of each step as written, wrapped at its commas: rows tall enough for
    # Streamlit to wrap text (row_height above 4 rem) when a model is long
    long_spec = max(len(h["spec"]) for h in hist) > 40
    widgets.dataframe(pd.DataFrame(hist).assign(spec=[widgets.spec_text(h["spec"]) for h in hist]),
                hide_index=True, key="history_table",
                row_height=72 if long_spec else None,
                column_config={"spec": st.column_config.TextColumn(
                                   "model", width="large",
                                   help="The model of each step as written"),
                               # wide enough for "exclude 3 flagged outliers" uncut
                               "change": st.column_config.TextColumn("change",
                                                                     width="medium"),
                               "rms_um": st.column_config.NumberColumn("RMS (µm)",
                                                                       format="%.3f"),
                               "chi2_dof": st.column_config.NumberColumn("χ²/dof",
                                                                         format="%.2f"),
                               "bic": st.column_config.NumberColumn("BIC", format="%.1f"),
                               "gp_amplitude_um": st.column_config.NumberColumn(
                                   "GP discrepancy (µm)", format="%.3f")})
with c2:
    if all(h["gp_amplitude_um"] is None for h in hist):
        st.caption("GP discrepancy amplitude (µm): tick the box above to compute it.")
    model = parse_spec(s["spec"], default_order=int(s["order"]))
    removable = ([f"-{e}" for e in model.effects] + [f"-{n}" for n, _ in model.active]
                 + [f"-{t}" for t, fn in PERIODIC.items() if fn in dict(model.periods)])
    def _removal_words(token):
        try:
            return f"{token} (drop {catalogue_entry(token[1:]).title})"
        except (KeyError, ValueError):
            return token

    rm = (st.selectbox("Remove from the model", removable, key="w_remove",
                       format_func=_removal_words,
                       help="A model-spec token: '-dxx' drops the X positioning function "
                            "from the model, '-plate_sag' the plate sag.")
          if removable else None)
    b1, b2 = st.columns(2)
    b1.button("Remove", key="remove_effect", disabled=rm is None, on_click=state.apply_selected,
              args=("w_remove",))
    b2.button("Undo last step", key="undo_step", disabled=len(s["history"]) < 2,
              on_click=state.undo_change)

with st.expander("Residual vectors at the worst observations"):
    rf = r.residuals_frame()
    rf["norm_um"] = np.linalg.norm(r.residuals_um, axis=1)
    widgets.dataframe(rf.nlargest(15, "norm_um"), hide_index=True, key="diag_worst")
