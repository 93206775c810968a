"""Rod calibration on certified ring gauges: base lengths, their budget, and which calibration a rod uses."""

import math
from dataclasses import replace

import numpy as np
import polars as pl
import pytest

from borescan import rawio, rod_calibration
from borescan.calibrations import choose_rod_calibration
from borescan.config import schema_defaults
from borescan.effects import Effect
from borescan.geometry import Hole, RodAxis, RodLayer
from borescan import measure
from borescan.rod import solve_rod
from borescan.synthetic.scenes import RodScene
from borescan.synthetic.simulate import simulate_rod, write_simulated

UNC = schema_defaults()["uncertainty"]
CTE = 11.5e-6
#: true layers: base lengths 12.3 um longer / 8.7 um shorter than the design's 71.0 mm, beams off the axis
TRUE = (
    RodLayer(1, 100.0, 71.0123, 0.0, 0.31, math.radians(0.27)),
    RodLayer(2, 400.0, 70.9913, 0.04, -0.22, math.radians(-0.18)),
)
DESIGN = tuple(replace(lay, l0_mm=71.0, phi_rad=0.0, d_mm=0.0, gamma_rad=0.0) for lay in TRUE)
GAUGE_D = (150.0021, 149.9987)
GAUGE_SET = {
    "id": "RGS-150",
    "type": "ring_gauge",
    "u_diameter_mm": 0.0012,
    "k": 2,
    "certificate": "RGS-150/2026-02",
    "cte_per_k": CTE,
    "features": [
        {"id": "H1", "z_mm": 100.0, "certified_diameter_mm": GAUGE_D[0], "gauge_id": "RG-150A"},
        {"id": "H2", "z_mm": 400.0, "certified_diameter_mm": GAUGE_D[1], "gauge_id": "RG-150B"},
    ],
}


def _scene(d_mm, rng, temp_c=20.0):
    """Return the rod held skew to the holes as the procedure asks: deflected across its eccentricity, so
    the layers' offsets are not collinear with the axis (along it the radii are barely determined,
    rod.py, and the solve says so with a large u).
    """
    e = float(rng.uniform(0.5, 1.5))
    az = float(rng.uniform(0, 2 * np.pi))
    axis = RodAxis(
        e * math.cos(az),
        e * math.sin(az),
        math.radians(float(rng.uniform(0.12, 0.2))),
        az + math.pi / 2 + float(rng.uniform(-0.5, 0.5)),
    )
    return RodScene(
        layers=TRUE,
        holes=(Hole((0.0, 0.0), d_mm[0] / 2), Hole((0.012, -0.021), d_mm[1] / 2)),
        axis=axis,
        range_mm=(8.0, 8.0),
        sample_rate_hz=100.0,
        cte_per_k=CTE,
        temperature_c=temp_c,
    )


def _sim(d_mm, seed, kind, artifact, temp_c=20.0, scan_id="SIM-ROD", effects=()):
    rng = np.random.default_rng(seed)
    eff = [Effect("thermal_expansion", {"temperature_c": temp_c})] if temp_c != 20.0 else []
    eff = eff + list(effects)
    return simulate_rod(
        _scene(d_mm, rng, temp_c),
        n_poses=24,
        samples_per_pose=5,
        kind=kind,
        artifact=artifact,
        features=("H1", "H2"),
        seed=seed + 1,
        nominal_layers=DESIGN,
        effects=eff,
        scan_id=scan_id,
    )


def _raw(sim, tmp_path):
    folder = write_simulated(sim, tmp_path / "raw", tmp_path / "truth")
    return rawio.read_scan(folder, raw_root=tmp_path / "raw")


#: the config without the layer-geometry draws (``rod_layer_geometry_draws`` 0): these rods' design
#: is near their truth and the draws' own checks are tests/test_rod_layer_geometry.py (they cost 24
#: solves per hold)
UNC_NO_DRAWS = dict(UNC, rod_layer_geometry_draws=0)


def _calibrate(scan):
    """Calibrate l0 in ``scan`` as the stage does (from the design in its scan.json; no geometry draws)."""
    return rod_calibration.calibrate_hold(scan, UNC_NO_DRAWS)


def _rows(scan):
    """Return the ``calibrations`` rows of the calibration in ``scan`` (with budget, hold, draws)."""
    return _calibrate(scan).rows(scan.night, None, UNC["coverage_probability"])


def test_layer_gauges_from_a_gauge_set_a_single_ring_or_refused():
    meta = {
        "artifact": GAUGE_SET,
        "rod": {"layers": [{"channel": 1, "feature": "H1"}, {"channel": 2, "feature": "H2"}]},
    }
    g = rod_calibration.layer_gauges(meta, [1, 2])
    assert [x["id"] for x in g] == ["RG-150A", "RG-150B"]
    assert [x["certified_diameter_mm"] for x in g] == list(GAUGE_D)
    assert all(
        x["u_diameter_mm"] == 0.0012 and x["k"] == 2 and x["certificate"] == "RGS-150/2026-02" for x in g
    )
    ring = {
        "id": "RG-150",
        "type": "ring_gauge",
        "certified_diameter_mm": 150.001,
        "u_diameter_mm": 0.001,
        "certificate": "C1",
    }
    g = rod_calibration.layer_gauges(dict(meta, artifact=ring), [1, 2])
    assert [x["id"] for x in g] == ["RG-150", "RG-150"] and g[0]["k"] == 2
    part = {"id": "P", "type": "part", "features": [{"id": "H1", "nominal_diameter_mm": 150.0}]}
    with pytest.raises(ValueError, match=r"rod layer 1 \(feature 'H1'\) has no certified diameter"):
        rod_calibration.layer_gauges(dict(meta, artifact=part), [1, 2])


def test_calibrated_base_lengths_make_the_solve_return_the_gauges(tmp_path):
    """The fixed point holds (radius = gauge radius at T within 1e-7 mm) and l0 moves towards the truth."""
    scan = _raw(_sim(GAUGE_D, 3, "calibration", GAUGE_SET, temp_c=21.0), tmp_path)
    hold = _calibrate(scan)
    layers, budget = hold.calibration.layers, hold.calibration.budget
    again = solve_rod(
        hold.means_mm,
        layers=layers,
        u_reading_mm=hold.u_mean_mm,
        coaxiality_mm=rod_calibration.rod_coaxiality_mm(UNC),
    )
    # the gauges at the scan's temperature (spec thermal_expansion: R = R20 (1 + alpha (T - 20)))
    radius_t = [0.5 * d * (1 + CTE * 1.0) for d in GAUGE_D]
    np.testing.assert_allclose(again.radius_mm, radius_t, atol=2e-7)
    assert [g["radius_at_t_mm"] for g in hold.calibration.gauges] == pytest.approx(radius_t, abs=1e-12)
    err = np.array([c.l0_mm - t.l0_mm for c, t in zip(layers, TRUE)])
    assert np.all(np.abs(err) <= 3 * budget.u()), (err, budget.u())


def test_calibrate_then_measure_removes_the_base_length_error(tmp_path):
    """Closed loop over seeds: a part measured with the design l0 is off by about 2 dl0 (+-25 um on
    layer 1); with the gauge calibration every diameter is within 4 sigma of the chain's scatter
    (2 sqrt 2 x 1.5 um in radius -> 12 um) of the truth and within 3 u of its own budget.
    """
    part = {
        "id": "CYL",
        "type": "part",
        "cte_per_k": CTE,
        "features": [
            {"id": "H1", "z_mm": 100.0, "nominal_diameter_mm": 150.0},
            {"id": "H2", "z_mm": 400.0, "nominal_diameter_mm": 150.0},
        ],
    }
    d_part = (150.0082, 149.9941)
    cal_err, design_err, design_u = [], [], []
    for seed in range(5):
        cal = _raw(
            _sim(GAUGE_D, 100 + seed, "calibration", GAUGE_SET, scan_id=f"CAL{seed}"), tmp_path / f"c{seed}"
        )
        cal_rows = _rows(cal)
        meas = _raw(
            _sim(d_part, 200 + seed, "measurement", part, scan_id=f"MEAS{seed}"), tmp_path / f"m{seed}"
        )
        # with the budget: the rows of a recorded calibration; the design geometry's: no record
        res = measure.rod_diameters_with_budget(meas, cal_rows, UNC, "C")
        nominal = measure.rod_diameters_with_budget(
            meas, [dict(r, l0_mm=71.0, calibration_json=None) for r in cal_rows], UNC, "N"
        )
        for r, n, d in zip(res, nominal, d_part):
            assert r["traceable"] and not n["traceable"]
            cal_err.append(r["diameter_mm"] - d)
            design_err.append(n["diameter_mm"] - d)
            design_u.append(n["du"].combined_t.u)
            assert abs(r["diameter_mm"] - d) <= 3 * r["du"].combined_t.u
            # the calibration's budget is in the diameter's (its readings and gauges), none in the design's
            keys = {tt.input.key for tt in r["du"].budget.terms}
            assert {f"fit:CAL{seed}:readings", "gauge:RG-150A@RGS-150/2026-02:D20"} <= keys, keys
            assert not any(
                k.startswith(("fit:CAL", "gauge:")) for k in (tt.input.key for tt in n["du"].budget.terms)
            )
    cal_err, design_err = np.array(cal_err).reshape(-1, 2), np.array(design_err).reshape(-1, 2)
    # each within 3 u (above); together far below the design geometry's error of layer 1 (> 20 um)
    assert np.sqrt(np.mean(cal_err**2)) < 0.5 * np.min(np.abs(design_err[:, 0])), cal_err * 1e3
    # layer 1's l0 is 12.3 um longer than designed: the design geometry's diameters 24.6 um short
    l0_short = 2 * (TRUE[0].l0_mm - DESIGN[0].l0_mm)
    design_u = np.array(design_u).reshape(-1, 2)
    assert np.all(np.abs(design_err[:, 0] + l0_short) < 3 * design_u[:, 0]), design_err * 1e3
    assert np.all(design_err[:, 0] < -0.5 * l0_short), design_err * 1e3


def test_budget_sensitivities_are_the_closed_forms(tmp_path):
    """l0 = l0_start + R20 (1 + alpha (T - 20)) - r: dl0/dD_g = f/2 on the gauge's own layer, dl0/dT = R20
    alpha,
    dl0/dalpha = R20 (T - 20), -1 on each sensor's linearity; one ring for both layers correlates them.
    """
    ring = {
        "id": "RG-150",
        "type": "ring_gauge",
        "certified_diameter_mm": 150.0021,
        "u_diameter_mm": 0.0012,
        "k": 2,
        "certificate": "C1",
        "cte_per_k": CTE,
    }
    scan = _raw(_sim((150.0021, 150.0021), 7, "calibration", ring, temp_c=21.5), tmp_path)
    b = _calibrate(scan).calibration.budget
    terms = {t.input.key: t for t in b.terms}
    f = 1 + CTE * 1.5
    np.testing.assert_allclose(terms["gauge:RG-150@C1:D20"].sensitivity, [f / 2, f / 2], rtol=1e-12)
    np.testing.assert_allclose(
        terms[f"temperature:{scan.scan_id}"].sensitivity, [75.00105 * CTE] * 2, rtol=1e-12
    )
    np.testing.assert_allclose(terms["cte:RG-150@C1"].sensitivity, [75.00105 * 1.5] * 2, rtol=1e-12)
    np.testing.assert_allclose(terms[f"linearity:rodcal:{scan.scan_id}:ch1"].sensitivity, [-1.0, 0.0])
    assert terms[f"linearity:rodcal:{scan.scan_id}:ch1"].input.u == pytest.approx(0.0025 * 8.0 / math.sqrt(3))
    cov = b.covariance()
    shared = (
        (f / 2) ** 2 * 0.0006**2
        + (75.00105 * CTE * terms[f"temperature:{scan.scan_id}"].input.u) ** 2
        + (75.00105 * 1.5 * terms["cte:RG-150@C1"].input.u) ** 2
    )
    assert cov[0, 1] == pytest.approx(shared, rel=1e-9)


def _cals(*rows):
    return pl.DataFrame(
        [
            {"calibration_id": c, "device_id": "ROD-01", "valid_from": v, "method": m, "channel": 1}
            for c, v, m in rows
        ]
    )


def test_a_rod_uses_its_gauge_calibration_else_its_design_geometry_by_policy():
    cals = _cals(("ROD-01-nominal-1", "2026-11-01", "nominal"), ("ROD-01-cal", "2026-11-10", "rod_gauge"))
    assert choose_rod_calibration(cals, set(), "ROD-01", "2026-11-12", 30, False) == ("ROD-01-cal", None)
    # before its first gauge calibration: the design geometry, or refused
    assert choose_rod_calibration(cals, set(), "ROD-01", "2026-11-05", 30, False) == (
        "ROD-01-nominal-1",
        None,
    )
    cid, why = choose_rod_calibration(cals, set(), "ROD-01", "2026-11-05", 30, False, "refuse")
    assert cid is None and "no calibration on certified ring gauges" in why
    # an expired or failed gauge calibration is refused, never replaced by the design geometry
    cid, why = choose_rod_calibration(cals, set(), "ROD-01", "2026-12-20", 30, False)
    assert cid is None and "expired" in why
    cid, why = choose_rod_calibration(cals, {"ROD-01-cal"}, "ROD-01", "2026-11-12", 30, False)
    assert cid is None and "failed its verification" in why
    assert choose_rod_calibration(cals, {"ROD-01-cal"}, "ROD-01", "2026-11-12", 30, True) == (
        "ROD-01-cal",
        None,
    )
    with pytest.raises(ValueError, match="rod_without_calibration"):
        choose_rod_calibration(cals, set(), "ROD-01", "2026-11-12", 30, False, "maybe")


def test_a_rod_calibration_scan_without_certified_rings_is_set_aside_naming_scan_json(tmp_path):
    """Bad input: the scan is quarantined with the file (scan.json) and the layer named, no
    calibration row is made, its raw files are untouched; a good scan beside it is calibrated.
    """
    import hashlib
    import json as _json

    from borescan import night_config
    from borescan.stages.calibrate_jobs import CalibrationOutcome, RodCalibrationContext
    from borescan.stages.calibrate_rod import calibrate_rod_scan

    dflt = schema_defaults()
    part = {
        "id": "CYL",
        "type": "part",
        "features": [{"id": "H1", "nominal_diameter_mm": 150.0}, {"id": "H2", "nominal_diameter_mm": 150.0}],
    }
    bad_scan = _raw(_sim(GAUGE_D, 5, "calibration", part, scan_id="CAL-NO-CERT"), tmp_path)
    good_scan = _raw(_sim(GAUGE_D, 6, "calibration", GAUGE_SET, scan_id="CAL-OK"), tmp_path)
    before = {
        p: hashlib.sha256(p.read_bytes()).hexdigest() for p in (tmp_path / "raw").rglob("*") if p.is_file()
    }
    ctx = RodCalibrationContext(
        UNC,
        dflt["laboratory"],
        dflt["verification"],
        pl.DataFrame(schema={"scan_id": pl.Utf8, "status": pl.Utf8, "kind": pl.Utf8, "device_id": pl.Utf8}),
    )  # no verification scans that night
    night_config.settle(tmp_path / "results", ["2026-11-20"], dflt)  # as the workflow does first
    made = CalibrationOutcome()
    for scan in (bad_scan, good_scan):
        made = made + calibrate_rod_scan(
            scan, "2026-11-20", tmp_path / "results", ctx, dflt["calibration"], lambda _m: None
        )
    bad, rows, links = list(made.quarantined), list(made.calibration_rows), list(made.calibration_scan_rows)
    assert [(q.scan_id, q.file) for q in bad] == [("CAL-NO-CERT", "scan.json")]
    assert "rod layer 1 (feature 'H1') has no certified diameter" in bad[0].reason
    rec = _json.loads((tmp_path / "results" / "quarantine" / "CAL-NO-CERT.json").read_text())
    assert rec["file"] == "scan.json" and rec["scan_id"] == "CAL-NO-CERT"
    assert {r["scan_id"] for r in rows} == {"CAL-OK"} and len(rows) == 2  # one row per layer of the good scan
    assert [link["scan_id"] for link in links] == ["CAL-OK"]  # one calibration_scans row
    # the good scan's certificate has the residuals.png its records section points to (outputs.md)
    (folder,) = {p.parent for p in (tmp_path / "results" / "calibration").rglob("certificate.pdf")}
    assert sorted(p.name for p in folder.iterdir()) == [
        "certificate.dcc.xml",
        "certificate.json",
        "certificate.pdf",
        "residuals.png",
    ]
    assert before == {
        p: hashlib.sha256(p.read_bytes()).hexdigest() for p in (tmp_path / "raw").rglob("*") if p.is_file()
    }


def test_a_rod_calibration_hold_that_fixes_no_radii_is_set_aside_with_what_would(tmp_path):
    """A calibration hold whose poses are bunched: the solve refuses it; the scan is quarantined
    naming lds.parquet, the solve's reason and the hold that would do.
    """
    from borescan import night_config
    from borescan.stages.calibrate_jobs import RodCalibrationContext
    from borescan.stages.calibrate_rod import calibrate_rod_scan

    dflt = schema_defaults()
    scene = _scene(GAUGE_D, np.random.default_rng(7))
    sim = simulate_rod(
        scene,
        np.linspace(0.0, 0.2, 24),  # the poses bunched within 11 deg
        samples_per_pose=5,
        kind="calibration",
        artifact=GAUGE_SET,
        features=("H1", "H2"),
        seed=8,
        nominal_layers=DESIGN,
        scan_id="CAL-BUNCHED",
    )
    scan = _raw(sim, tmp_path)
    ctx = RodCalibrationContext(
        UNC,
        dflt["laboratory"],
        dflt["verification"],
        pl.DataFrame(schema={"scan_id": pl.Utf8, "status": pl.Utf8, "kind": pl.Utf8, "device_id": pl.Utf8}),
    )
    night_config.settle(tmp_path / "results", ["2026-11-20"], dflt)
    made = calibrate_rod_scan(
        scan, "2026-11-20", tmp_path / "results", ctx, dflt["calibration"], lambda _m: None
    )
    assert not made.calibration_rows
    (q,) = made.quarantined
    assert (q.scan_id, q.file) == ("CAL-BUNCHED", "lds.parquet")
    assert "degenerate geometry" in q.reason and "deflected across its eccentricity" in q.reason
    assert "borescan plan --rod-scan" in q.reason


def test_rod_verification_names_its_largest_input_and_what_would_reduce_it(tmp_path):
    """Each layer's row names the budget's largest contribution; when U(E) is not below the tolerance
    (a 1 um tolerance here) it says what would reduce it, and nothing when the verdict is decided.
    """
    cal = _raw(_sim(GAUGE_D, 11, "calibration", GAUGE_SET, scan_id="CALV"), tmp_path / "c")
    rows = _rows(cal)
    ver = _raw(_sim(GAUGE_D, 12, "verification", GAUGE_SET, scan_id="VERV"), tmp_path / "v")
    res = measure.rod_diameters_with_budget(ver, rows, UNC, "C")
    lab = schema_defaults()["laboratory"]
    tight = measure.rod_verifications(ver, res, "C", UNC, lab, 0.001)
    for row in tight:
        top = max(row["budget"], key=lambda b: abs(b["contribution"]))
        assert row["dominant_input"] == top["key"]
        kind = top["key"].split(":")[0]
        expect = {
            "linearity": "linearity",
            "fit": "a calibration with more poses",
            "readings": "poses",
        }
        assert expect.get(kind, "stated") in row["dominant_fix"]
    loose = measure.rod_verifications(ver, res, "C", UNC, lab, 1.0)
    assert all(r["dominant_fix"] is None and r["dominant_input"] for r in loose)
    # the two columns reach the stage table and the catalog (outputs.md's verifications, extended)
    from borescan import catalog, tables

    cols = tables.polars_schema("verifications")
    stage = tables.frame("verifications", [{k: v for k, v in r.items() if k in cols} for r in tight])
    catalog.build_catalog(tmp_path / "results", {"verifications": stage})
    con = catalog.open_catalog(tmp_path / "results")
    got = con.execute(
        "SELECT feature, dominant_input, dominant_fix FROM verifications ORDER BY feature"
    ).fetchall()
    con.close()
    assert got == sorted((r["feature"], r["dominant_input"], r["dominant_fix"]) for r in tight)


def test_linearity_curve_is_absorbed_by_the_calibration_up_to_its_change(tmp_path):
    """A sensor's data-sheet linearity is one curve read in every hold (simulated truth: the spec's
    bow, a = 20 um = the data sheet's 0.0025 x 8 mm on both sensors). The calibration's l0 absorbs it
    at the gauges' readings; a verification in the same gauges is off only by the curve's change
    between the holds. The budget says so: the calibration's linearity input cancels (sensitivity 0
    on D) and the change term's bound (Markov, cubic) covers the error the curve makes, which is far
    below the 2 a a whole curve could make.
    """
    bow = [Effect("sensor_nonlinearity", {"channel": c, "a_mm": 0.02}) for c in (1, 2)]
    d_with, d_without, budgets = [], [], []
    for effects, out in ((bow, d_with), ((), d_without)):
        base = tmp_path / ("bow" if effects else "clean")
        cal = _raw(_sim(GAUGE_D, 31, "calibration", GAUGE_SET, scan_id="CALL", effects=effects), base / "c")
        rows = _rows(cal)
        ver = _raw(_sim(GAUGE_D, 32, "verification", GAUGE_SET, scan_id="VERL", effects=effects), base / "v")
        res = measure.rod_diameters_with_budget(ver, rows, UNC, "C")
        out.extend(r["diameter_mm"] for r in res)
        budgets.append([r["du"].budget for r in res])
    a = 0.0025 * 8.0
    for j, b in enumerate(budgets[0]):
        terms = {t.input.key: t for t in b.terms}
        cal_key = f"linearity:rodcal:CALL:ch{j + 1}"
        assert np.allclose(terms[cal_key].sensitivity, 0.0, atol=1e-12)  # absorbed, then read again
        (change,) = [t for k, t in terms.items() if k.startswith("linearity:VERL/")]
        half = change.input.u * math.sqrt(3.0)
        assert 0 < half <= 2 * a  # at most a whole curve at each hold (8 mm sensors read much of it here)
        # the curve's effect on the diameter (same noise, with and without it): within the bound
        assert abs(d_with[j] - d_without[j]) <= 2.0 * half


def test_linearity_change_bound_is_markovs_and_holds_for_cubic_curves():
    """The bound of measure.linearity_change_mm: Chebyshev's T3 (|T3| <= 1) attains Markov's slope
    2 n^2 a / R at the end of the range, the curvature term is Markov's, and over random cubics
    bounded by a and random holds (24 poses around a mean reading, uneven) the change of the
    hold-averaged curve stays within it (exact for a cubic: mean, variance and third moment).
    """
    from borescan.measure import linearity_change_mm

    a, R = 0.01, 30.0
    cheb = np.polynomial.chebyshev.Chebyshev([0, 0, 0, a], domain=[0, R])
    h = 1e-4
    slope = (cheb(R) - cheb(R - h)) / h

    def hold(mean_mm, var_mm2=0.0, m3_mm3=0.0):
        return {"mean_mm": mean_mm, "var_mm2": var_mm2, "m3_mm3": m3_mm3}

    assert linearity_change_mm(a, R, hold(R - h), hold(R), 3) == pytest.approx(abs(slope) * h, rel=1e-3)
    assert linearity_change_mm(a, R, hold(0.0), hold(R), 3) == 2 * a  # never more than twice the curve
    # the curvature term: T3'' = 24 at the end (Markov's n^2 (n^2 - 1) / 3), (2 / R)^2 a per mm^2
    assert linearity_change_mm(a, R, hold(15.0, 1.0), hold(15.0, 2.0), 3) == pytest.approx(
        0.5 * 24 * (2 / R) ** 2 * a * 1.0, rel=1e-12
    )
    rng = np.random.default_rng(7)
    u = np.linspace(0, R, 3001)
    worst = 0.0
    for _ in range(300):
        p = np.polynomial.Polynomial(rng.standard_normal(4), domain=[0, R])
        p = p * (a / np.max(np.abs(p(u))))
        holds = []
        for _h in range(2):
            v = rng.uniform(2, R - 2) + rng.uniform(0.2, 2.0) * np.cos(rng.uniform(0, 2 * np.pi, 24))
            holds.append((hold(v.mean(), v.var(), np.mean((v - v.mean()) ** 3)), p(v).mean()))
        (h1, f1), (h2, f2) = holds
        bound = linearity_change_mm(a, R, h1, h2, 3)
        assert abs(f2 - f1) <= bound * (1 + 1e-9)
        worst = max(worst, abs(f2 - f1) / bound)
    assert worst > 0.2  # a bound, not a wild over-estimate
