"""Benchmark: the HTML report of the sample analysis record (thesis data), time and size.

Ours: ``report.render`` of ``analysis.run(record)`` (plotly.js and the figure data packed
once; the first call in a process also packs plotly.js, reported as "cold"). Peer in the
same run, on the same fit: the per-figure assembly (every figure with its own plotly.js,
plotly's ``to_html``), which runs against today's package. (The previous assembly, read
from an old commit with git, no longer imports against today's package: the comparison
with it is recorded in docs/performance.md, not re-run.)
Run: ``.venv/bin/python bench/report.py``.
"""

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _timing import median_time  # noqa: E402

from cmm_core import analysis as A  # noqa: E402
from cmm_core.analysis import report as rep  # noqa: E402

RECORD = ROOT / "sample_data" / "thesis" / "analysis.json"


def per_figure(res) -> str:
    """Every figure of the report with its own copy of plotly.js."""
    r = res.fit
    figs = [rep.fig_placements(res.dataset), rep.fig_error_functions(r)]
    figs += [rep.fig_deviation(r, p, res.record.magnification)
             for p in r.problem.obs.positions]
    figs += [rep.fig_pattern(r.table, r.residuals_um, "Residuals per observation (µm)")]
    if res.mpe is not None:
        figs.append(rep.fig_mpe(res.mpe))
    figs.append(rep.fig_history(list(res.history)))
    return "".join(f.to_html(full_html=False, include_plotlyjs=True) for f in figs)


def main():
    record = A.read_record(RECORD)
    t = time.perf_counter()
    res = A.run(record)
    t_run = time.perf_counter() - t
    t = time.perf_counter()
    cold = rep.render(res)
    t_cold = time.perf_counter() - t
    t_ours, ours = median_time(lambda: rep.render(res), 3)
    rows = [("ours (packed once)", t_ours, len(ours.encode()))]
    t_per, per = median_time(lambda: per_figure(res), 1)
    rows.append(("plotly.js per figure", t_per, len(per.encode())))
    print(f"record {RECORD.relative_to(ROOT)}: analysis.run {t_run:.2f} s (fit, history, "
          f"uncertainty, MPE); ours cold (packs plotly.js) {t_cold:.2f} s, "
          f"{len(cold.encode()) / 1e6:.2f} MB")
    print(f"{'report assembly':44s} {'median s':>9s} {'MB':>7s} {'time ratio':>11s}")
    for name, sec, size in rows:
        print(f"{name:44s} {sec:9.2f} {size / 1e6:7.2f} {t_ours / sec:11.2f}")


if __name__ == "__main__":
    main()
