"""Measure next, issue 40 (items 2 and 4): the rivals are the open question of the
verdict (a whole alias set, never one function at two orders, the baseline as given) and
a repeat is a measurement the lab can make next (appended to the placement still set up,
or in the next session with its set-up, timed after the data's last reading).

Reference values by hand: the pairs from hand-made candidates; the three-way scores
against the pairwise ones (λ of a pair does not depend on the third rival's columns:
the same rows, the same two rivals' columns); the times from the plan's time model
(0.5 min per ball, 10 min per placement, ``files.MEASUREMENT_DEFAULTS``)."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from scenarios import simulated  # noqa: E402
from test_proposals_cli import _parser  # noqa: E402

from cmm_core.diagnosis import Candidate, Diagnosis  # noqa: E402
from cmm_core.model import fit  # noqa: E402
from cmm_core.plan import (  # noqa: E402
    MEASUREMENT_DEFAULTS,
    append_measurement,
    check_rivals,
    fit_rivals,
    function_of,
    last_placement,
    measurement_candidates,
    open_pairs,
    plan_file,
    propose,
    read_plan,
    repeat_candidates,
    repeat_from_fit,
    rival_pairs,
    rivals_of,
    simulate_plan,
    truth_config,
)

PER_BALL = MEASUREMENT_DEFAULTS["minutes_per_ball"]
PER_PLACE = MEASUREMENT_DEFAULTS["minutes_per_placement"]


def _cand(effect, aliases=(), significant=True):
    """A ranked candidate as the diagnosis gives it (only what the rivals read matters)."""
    return Candidate(effect, effect, "", "", "", 1.0, 1.0, 10.0, 1, -5.0, 1e-4, significant,
                     True, np.zeros((0, 3)), list(aliases), level=1e-3)


def _row(effect, aliases=(), significant=True):
    return {"effect": effect, "aliases": list(aliases), "significant": significant}


# --- item 2: the rivals are the open question

def test_one_function_at_two_orders_is_never_a_pair():
    """rxz:3 with rxz:4 among its aliases: the same carriage rotation, left out of the
    set; the open question is rxz:3 against the alias of another function (sxy). With
    only the same function as alias, or as runner-up, there is no pair of it."""
    assert function_of("rxz:4") == function_of("rxz:3") == "rxz"
    assert function_of("periodic_x:40") == "periodic_x:40"  # a period, not an order
    assert rival_pairs([_row("rxz:3", ["rxz:4", "sxy"])]) == [("rxz:3", "sxy")]
    assert rival_pairs([_row("rxz:3", ["rxz:4"]), _row("rxz:4", ["rxz:3"])]) == []
    # the runner-up of another function is the next significant candidate past rxz:4
    got = rival_pairs([_row("rxz:3", ["rxz:4"]), _row("rxz:4"), _row("dzz:3")], top=1)
    assert got == [("rxz:3", "dzz:3")]
    d = Diagnosis(None, [_cand("rxz:3", ["rxz:4", "sxy"]), _cand("rxz:4", ["rxz:3"])],
                  None, {}, "")
    assert rivals_of(d) == ("rxz:3", "sxy")
    for pairs in (open_pairs(d), rival_pairs([_row("rxz:3", ["rxz:4"])])):
        assert all(len({function_of(r) for r in p}) == len(p) for p in pairs)
    with pytest.raises(ValueError, match="one function .rxz. at two orders"):
        check_rivals(("rxz:3", "rxz:4"))


@pytest.fixture(scope="module")
def drifting():
    """Drift hidden with styli in blocks (1 µm/h spread, noise 0.5 µm; seed 1003 of the
    bench's drift case): H, D1, D2 measured in that order, D2 last."""
    return simulated("pitch80_3pos", 1003, noise_um=0.5,
                     effects={"drift": {"sd_um_per_h": 1.0}}).dataset


def test_a_three_way_alias_set_is_considered_whole(drifting):
    """dzz:4 aliased with both probe_offset and drift: one question of three rivals (not
    two pairs of it), the default rivals whole; scored, each rival's Δχ², size and dof
    are those of its pairwise test against the rival it is hardest to tell from, the
    first rival's power (all at its level) the smaller of its two pairwise powers, and the
    set is decided with the minimum pairwise power."""
    trio = ("dzz:4", "probe_offset", "drift")
    rows = [_row("dzz:4", ["probe_offset", "drift"]), _row("probe_offset", ["dzz:4"])]
    assert rival_pairs(rows) == [trio]
    d = Diagnosis(None, [_cand("dzz:4", ["probe_offset", "drift"])], None, {}, "")
    assert rivals_of(d) == trio
    cands = [c for c in measurement_candidates(drifting)
             if c.name in ("repeat_all_4", "shift_x")]
    three = {p.candidate.name: p for p in propose(drifting, trio, cands=cands).ranked}
    assert set(three) == {"repeat_all_4", "shift_x"}
    pairs = {}
    for a, b in (("dzz:4", "probe_offset"), ("dzz:4", "drift"), ("probe_offset", "drift")):
        for p in propose(drifting, (a, b), cands=cands).ranked:
            pairs[(p.candidate.name, a, b)] = p
    for name, p in three.items():
        assert p.rivals == trio
        for t in trio:
            # the test against the rival hardest to tell from: one of its two pairwise
            each = [(q.delta_chi2_fitted[t], q.delta_chi2[t], tuple(q.dof[t]))
                    for (n, a, b), q in pairs.items() if n == name and t in (a, b)]
            assert len(each) == 2
            got = (p.delta_chi2_fitted[t], p.delta_chi2[t], tuple(p.dof[t]))
            assert any(got[2] == e[2] and got[:2] == pytest.approx(e[:2], rel=1e-6,
                                                                     abs=1e-9) for e in each)
        # dzz:4 first: its pairwise tests are at its own level, as all of the three's
        first = [q for (n, a, _), q in pairs.items() if n == name and a == "dzz:4"]
        hardest = min(first, key=lambda q: q.power_at_size["dzz:4"])
        assert p.power_at_size["dzz:4"] == pytest.approx(hardest.power_at_size["dzz:4"],
                                                         rel=1e-6, abs=1e-12)
        assert p.delta_chi2["dzz:4"] == pytest.approx(hardest.delta_chi2["dzz:4"], rel=1e-6,
                                                      abs=1e-9)
        assert p.power_min == pytest.approx(min(p.power.values()))
        assert "dzz:4, probe_offset and drift differ pairwise by at least" in p.outcome


def test_the_baseline_is_kept_verbatim_through_the_cli_json(rxz4_files):
    """``--baseline kinematic21,-sxy`` with sxy the first rival: the fitted spec of that
    rival is ``kinematic21`` (sxy added back), but the JSON's baseline is the user's."""
    args = _parser().parse_args(
        ["next", str(rxz4_files / "measurements.csv"), "--setup", str(rxz4_files / "setup.json"),
         "--certificate", str(rxz4_files / "certificate.csv"), "--baseline", "kinematic21,-sxy",
         "--rivals", "sxy,rxz:4", "--top", "1"])
    out = args.func(args)
    assert out["baseline"] == "kinematic21,-sxy"
    assert out["rivals"] == ["sxy", "rxz:4"]


# --- item 4: a repeat is a future measurement

def test_a_repeat_of_a_placement_taken_down_is_in_the_next_session(drifting):
    """H was measured first, D1 and D2 after it: its repeat is in the next session, the
    plate set up again (10 min), every reading after the data's last; the readings
    simulated (on the virtual CMM and from the fit) and the plan file carry those times,
    and the planner reads the repeat then."""
    m = drifting.meas
    t_last = float(m["time_min"].max())
    assert last_placement(drifting) == "D2"
    assert float(m.loc[m["position"] == "H", "time_min"].max()) < t_last
    cand = next(c for c in repeat_candidates(drifting, n_balls=4) if c.name == "repeat_H_4")
    r = cand.repeat["H"]
    assert "in the next session" in cand.description and "before its plate" not in \
        cand.description
    assert r["session"] == "next" and r["setup_min"] == PER_PLACE
    assert r["time_min"] == pytest.approx(t_last + PER_PLACE + PER_BALL * np.arange(1, 5))
    assert cand.time_min == pytest.approx(4 * PER_BALL + PER_PLACE)
    n = len(m)
    rf = fit_rivals(drifting, ("drift", "probe_offset"))
    cfg = {**truth_config(rf.fits["drift"]), "noise_um": 0.0}
    for aug in (append_measurement(drifting, cand, config=cfg),
                repeat_from_fit(drifting, cand, rf.fits["drift"])):
        new = aug.meas.iloc[n:]
        assert len(new) == 4 and (new["position"] == "H").all()
        assert new["time_min"].to_numpy() == pytest.approx(r["time_min"])
        assert (new["time_min"] > t_last).all()
    # the drift model sees the repeat at its own time: the fit of the data with it
    # counts H's hours out to the next session
    got = fit(append_measurement(drifting, cand, config=cfg), "kinematic21,drift",
              sigma_um=0.5, max_iter=2000)
    h = got.problem.obs.hours[got.problem.obs.table["position"].to_numpy() == "H"]
    first = float(m.loc[m["position"] == "H", "time_min"].min())
    assert np.ptp(h) == pytest.approx((r["time_min"][-1] - first) / 60.0, rel=1e-9)
    best = next(p for p in propose(drifting, ("drift", "probe_offset"), cands=[cand]).ranked)
    doc = plan_file(drifting, best, baseline="kinematic21,drift,probe_offset")
    again = doc["strategies"][1]["repeat_at_end"]["H"]
    assert again["time_min"] == pytest.approx(r["time_min"]) and again["setup_min"] == PER_PLACE
    pf = read_plan(doc, name="proposal")
    now, more = pf.strategies
    assert more.time_min - now.time_min == pytest.approx(cand.time_min)
    sim = simulate_plan(more).meas
    rep = sim[(sim["position"] == "H") & (sim["repeat"] > 0)]
    assert rep["time_min"].to_numpy() == pytest.approx(r["time_min"])


def test_the_last_placements_repeat_is_appended_to_it(drifting):
    """D2, measured last, is still set up: its repeat is appended to the current
    placement right after the data's last reading, with no set-up; ``repeat_all``
    appends there first, then sets up each other placement in turn."""
    m = drifting.meas
    t_last = float(m["time_min"].max())
    reps = {c.name: c for c in repeat_candidates(drifting, n_balls=4)}
    c = reps["repeat_D2_4"]
    r = c.repeat["D2"]
    assert "appended to the current placement D2" in c.description
    assert r["session"] == "current" and r["setup_min"] == 0.0
    assert r["time_min"] == pytest.approx(t_last + PER_BALL * np.arange(1, 5))
    assert c.time_min == pytest.approx(4 * PER_BALL)
    every = reps["repeat_all_4"].repeat
    assert list(every) == ["D2", "H", "D1"]
    assert every["D2"]["time_min"] == r["time_min"]
    starts = [every[p]["time_min"][0] for p in every]
    assert starts == pytest.approx([t_last + PER_BALL, every["D2"]["time_min"][-1]
                                    + PER_PLACE + PER_BALL,
                                    every["H"]["time_min"][-1] + PER_PLACE + PER_BALL])
    assert reps["repeat_all_4"].time_min == pytest.approx(12 * PER_BALL + 2 * PER_PLACE)
