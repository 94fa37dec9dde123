"""The app's sidebar (drawn by ``app.py`` on every page): the current dataset, model and
fit quality, the figure switch, and what still needs the user's attention."""

from __future__ import annotations

import streamlit as st

from cmm_core import analysis as A
from cmm_core.units import p_text
from pages.ui.cached import current_fit, pending_outliers
from pages.ui.calls import describe_error
from pages.ui.state import INSTRUMENT_NAMES, dataset
from pages.ui.widgets import INTERACTIVE, spec_markdown


def sidebar():
    """The sidebar of every page."""
    s = st.session_state
    sb = st.sidebar
    sb.toggle("Interactive plots", key=INTERACTIVE,
              help="Draw the 2-D figures with Plotly: zoom, pan and hover values, slower to "
                   "draw. Off: static pictures drawn on the server (hover a marker for its "
                   "label), the fast default.")
    sb.markdown("### Current analysis")
    try:
        ds = dataset()
    except Exception as exc:  # noqa: BLE001
        sb.error(describe_error(exc))
        return
    n_ex = len(s["exclusions"])
    setup = ds.setup
    sb.markdown(f"**Machine:** {setup.machine_id or 'not named (setup key machine.id)'}  \n"
                + (f"calibrated {setup.calibration_date}" if setup.calibration_date
                   else "calibration date not stated (setup key calibration_date)"))
    sb.markdown(f"**Dataset:** {ds.name}  \n{len(ds.meas)} probed ball centres"
                + (f" ({n_ex} excluded)" if n_ex else "")
                + f", {len(ds.positions)} positions, {len(ds.probes)} probes")
    files = s.get("ds_origin", {})
    sb.caption(f"Setup: {files.get('setup_source', 'setup of the dataset')}.  \n"
               f"Certificate: {files.get('certificate_source') or _cert_words(ds)}."
               + (f"  \nCertificate uncertainty: {ds.certificate.u_source}."
                  if ds.certificate is not None else "")
               + ("  \nInstruments fitted with the plate: " + ", ".join(
                   f"{n} ({INSTRUMENT_NAMES.get(k, k)})" for k, n, _ in s["instruments"])
                  + "." if s.get("instruments") else ""))
    if s.get("reset_note"):
        sb.caption("New dataset, settings reset to its defaults: "
                   + "; ".join(s["reset_note"]) + ".")
    spec, spec_help = spec_markdown(s["spec"])
    sb.markdown(f"**Model:** {spec}  \norder {s['order']}, plate {s['plate']}, "
                f"σ = {s['sigma_um']:g} µm", help=spec_help)
    r = current_fit(show_error=False)
    if r is None:
        sb.warning("No fit for these settings.")
    else:
        c1, c2 = sb.columns(2)
        c1.metric("RMS (µm)", f"{r.rms_um:.3f}")
        c2.metric("χ²/dof", f"{r.chi2_dof:.2f}")
        if r.fails_chi2_test:
            sb.warning(f"Fails the χ² test ({p_text(r.chi2_p_value)}, "
                       f"{A.chi2_test_numbers(r)[1]} dof): "
                       f"uncertainties from σ are too small by ×{r.birge_ratio:.2f}.")
        status = {"converged": "converged", "max_iterations": "NOT converged",
                  "failed": "fit failed"}.get(r.status, r.status)
        sb.caption(f"{status}; {r.n_obs} observations in the fit; rank {r.rank}"
                   + (f"; {len(r.null_combinations)} undetermined combination(s) of "
                      f"{len(r.unidentifiable)} parameters" if r.unidentifiable else ""))
    if n_ex:
        sb.caption(f"{n_ex} observation(s) excluded as outliers.")
    pending = pending_outliers(ds)
    if pending:
        # a coloured line, not a box: the Data page's summary is the one warning of it
        sb.caption(f":orange[{len(pending)} flagged outlier(s) still in the fit (see Data).]")
    if s.get("save_conflict"):
        sb.warning(f"Not saved: {s['save_conflict']}")
    if s.get("save_error"):
        sb.caption(f"Not kept for a reload: {s['save_error']} (the last good state is).")


def _cert_words(ds) -> str:
    if ds.certificate is None:
        return "none (plate geometry self-calibrated)"
    return "given with the dataset"
