"""Certified artifacts: a ring gauge's radius at the scan's temperature, its catalog row."""

import pytest

from borescan.artifacts import artifact_row, gauge_radius_mm, radius_at_temperature_mm


def test_radius_at_temperature_closed_form():
    # steel gauge, 275.029 mm at 20 degC, 11.5e-6 /K, at 25 degC: R = 137.5145 (1 + 5 * 11.5e-6)
    assert radius_at_temperature_mm(137.5145, 11.5e-6, 25.0) == pytest.approx(137.5145 * 1.0000575, rel=1e-15)
    assert radius_at_temperature_mm(137.5145, 11.5e-6, 20.0) == 137.5145
    assert radius_at_temperature_mm(100.0, 1e-5, 10.0) == pytest.approx(
        99.99, rel=1e-15
    )  # contracts below 20 degC


def test_gauge_radius_from_scan_json():
    meta = {
        "artifact": {"certified_diameter_mm": 275.029, "nominal_diameter_mm": 275.0, "cte_per_k": 11.5e-6},
        "environment": {"temperature_c": 20.6},
    }
    assert gauge_radius_mm(meta) == 0.5 * 275.029 * (1.0 + 11.5e-6 * (20.6 - 20.0))


def test_gauge_radius_defaults_nominal_diameter_20_degc_and_no_expansion():
    assert gauge_radius_mm({"artifact": {"nominal_diameter_mm": 280.0}}) == 140.0
    assert gauge_radius_mm({"artifact": {"nominal_diameter_mm": 280.0, "cte_per_k": 1e-5}}) == 140.0
    assert (
        gauge_radius_mm(
            {"artifact": {"certified_diameter_mm": 280.0}, "environment": {"temperature_c": 30.0}}
        )
        == 140.0
    )


def test_gauge_without_diameter_is_an_error():
    with pytest.raises(ValueError, match="neither certified_diameter_mm nor nominal_diameter_mm"):
        gauge_radius_mm({"artifact": {"id": "RG-275"}})
    with pytest.raises(ValueError, match="neither"):
        gauge_radius_mm({})


def test_artifact_row():
    meta = {"artifact": {"id": "RG-275", "type": "ring_gauge", "certified_diameter_mm": 275.029, "k": 2}}
    row = artifact_row(meta)
    assert (
        row["artifact_id"] == "RG-275"
        and row["certified_diameter_mm"] == 275.029
        and row["cte_per_k"] is None
    )
    assert artifact_row({"artifact": {"type": "part"}}) is None and artifact_row({}) is None


# --- a certificate keeps the value it was first recorded with (history cannot be rewritten) ---


def _rec(sid, night, value, cert="RG-275/2026-03", u=0.0015, started="2026-11-20T01:00:00Z", status="ok"):
    return {
        "scan_id": sid,
        "night": night,
        "status": status,
        "started_at": started,
        "artifact_id": "RG-275",
        "artifact_certificate": cert,
        "artifact_certified_diameter_mm": value,
        "artifact_u_diameter_mm": u,
    }


def test_certificate_conflicts_name_both_values_and_the_first_scan():
    from borescan.artifacts import certificate_conflicts

    earlier = [_rec("A", "2026-11-20", 275.029)]
    tonight = [
        _rec("B", "2026-11-21", 276.5, started="2026-11-21T01:00:00Z"),  # typo under the same certificate
        _rec("C", "2026-11-21", 276.5, cert="RG-275/2027-01"),  # recertified: a new certificate id
        _rec("D", "2026-11-21", 275.029, u=0.003),  # same value, other uncertainty
        _rec("E", "2026-11-21", 275.029),
    ]  # agrees
    out = certificate_conflicts(earlier, tonight)
    assert set(out) == {"B", "D"}
    assert "276.5 here, 275.029 in scan A (night 2026-11-20)" in out["B"]
    assert "certificate RG-275/2026-03" in out["B"] and "new certificate id" in out["B"]
    assert "u_diameter_mm 0.003 here, 0.0015 in scan A" in out["D"]
    # within one night the earlier scan (started_at, then scan_id) is the record; a quarantined row is none
    out = certificate_conflicts(
        [_rec("Q", "2026-11-19", 1.0, status="quarantined")],
        [
            _rec("Y", "n", 276.5, started="2026-11-21T02:00:00Z"),
            _rec("X", "n", 275.029, started="2026-11-21T01:00:00Z"),
        ],
    )
    assert set(out) == {"Y"} and "in scan X" in out["Y"]
    # rows without a certificate id or a certified value are not checked
    assert certificate_conflicts(earlier, [_rec("F", "n", None), _rec("G", "n", 1.0, cert=None)]) == {}


def test_a_gauge_set_keeps_each_rings_certified_value():
    """A rod's gauge set states a certified diameter per feature: another value for one ring under
    the same certificate is a conflict too, named with the feature.
    """
    import json

    from borescan.artifacts import certificate_conflicts, certificate_fields

    def meta(h1, h2):
        return {
            "artifact": {
                "id": "RGS-150",
                "type": "ring_gauge",
                "certificate": "RGS-150/2026-02",
                "u_diameter_mm": 0.0012,
                "features": [
                    {"id": "H1", "certified_diameter_mm": h1},
                    {"id": "H2", "certified_diameter_mm": h2},
                ],
            }
        }

    f = certificate_fields(meta(150.0021, 149.9987))
    assert f["artifact_certified_diameter_mm"] is None
    assert json.loads(f["artifact_features_certified"]) == {"H1": 150.0021, "H2": 149.9987}

    def rec(sid, night, h1, h2):
        return dict(
            certificate_fields(meta(h1, h2)),
            scan_id=sid,
            night=night,
            status="ok",
            artifact_id="RGS-150",
            started_at=f"{night}T01:00:00Z",
        )

    out = certificate_conflicts(
        [rec("A", "2026-11-20", 150.0021, 149.9987)],
        [rec("B", "2026-11-21", 150.0021, 149.9897), rec("C", "2026-11-21", 150.0021, 149.9987)],
    )
    assert set(out) == {"B"}
    assert "feature H2 certified_diameter_mm 149.9897 here, 149.9987 in scan A (night 2026-11-20)" in out["B"]


def _gauge_scan(raw, truth, sid, night, diameter_mm, cert):
    from borescan.synthetic import scenes, simulate

    scene = scenes.default_tri_scene()
    art = {
        "id": "RG-275",
        "type": "ring_gauge",
        "nominal_diameter_mm": 275.0,
        "certified_diameter_mm": diameter_mm,
        "u_diameter_mm": 0.0015,
        "k": 2,
        "certificate": cert,
        "cte_per_k": scene.cte_per_k,
    }
    sim = simulate.simulate_tri_spindle(scene, scan_id=sid, night=night, n_rev=3, seed=1, artifact=art)
    simulate.write_simulated(sim, raw, truth)


def test_ingest_and_validate_set_aside_a_scan_that_rewrites_a_certificate(tmp_path):
    from borescan import validation
    from borescan.stages.ingest import stage_ingest

    raw, truth, res = tmp_path / "raw", tmp_path / "truth", tmp_path / "results"
    _gauge_scan(raw, truth, "N1-CAL", "2026-11-20", 275.029, "RG-275/2026-03")
    # a transposition typo (275.092 for 275.029): plausible against the nominal 275, so only the certificate
    # recorded by an earlier scan can tell
    _gauge_scan(raw, truth, "N2-CAL-TYPO", "2026-11-21", 275.092, "RG-275/2026-03")
    _gauge_scan(raw, truth, "N2-CAL-RECERT", "2026-11-21", 275.031, "RG-275/2027-01")
    s1, _, bad1 = stage_ingest(raw, "2026-11-20", res)
    assert bad1 == [] and s1["artifact_certified_diameter_mm"].to_list() == [275.029]
    s2, _, bad2 = stage_ingest(raw, "2026-11-21", res, earlier_scans=[s1])
    status = dict(zip(s2["scan_id"], s2["status"]))
    assert status == {"N2-CAL-TYPO": "quarantined", "N2-CAL-RECERT": "ok"}
    assert [q.scan_id for q in bad2] == ["N2-CAL-TYPO"] and bad2[0].file == "scan.json"
    assert "275.092 here, 275.029 in scan N1-CAL (night 2026-11-20)" in bad2[0].reason
    assert (res / "quarantine" / "N2-CAL-TYPO.json").exists()
    # 'flag' keeps the scan (the conflict is logged)
    lines = []
    s2f, _, bad2f = stage_ingest(
        raw, "2026-11-21", tmp_path / "r2", earlier_scans=[s1], on_conflict="flag", log=lines.append
    )
    assert bad2f == [] and set(s2f["status"]) == {"ok"} and any("N2-CAL-TYPO" in x for x in lines)
    # borescan validate gives the same verdict
    rep = validation.validate_tree(raw)
    assert rep.bad_scan_ids == {"N2-CAL-TYPO"}
    assert [p.file for p in rep.problems] == ["scan.json"] and "275.092 here" in rep.problems[0].problem
