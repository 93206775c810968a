"""The rod hold plan (borescan.plan_rod): predictions against the spread of simulated holds, the
hold a solve describes, and the recommendation's choice.
"""

import math
from dataclasses import replace

import numpy as np

from borescan.geometry import Hole, RodAxis, RodLayer, rod_readings
from borescan.plan_rod import RodHold, hold_of_solution, predict_rod, recommend_rod
from borescan.rod import rod_crb, solve_rod

GEOM = (
    RodLayer(1, 100.0, 71.0, phi_rad=0.02, d_mm=0.3, gamma_rad=np.deg2rad(0.3)),
    RodLayer(2, 400.0, 71.0, phi_rad=-0.05, d_mm=-0.2, gamma_rad=np.deg2rad(-0.4)),
)
HOLES = (Hole((0.0, 0.0), 75.0), Hole((0.01, -0.02), 75.012))
AXIS = RodAxis(1.0, 0.5, np.deg2rad(0.3), math.atan2(0.5, 1.0) + math.pi / 2)  # skew across e
SIG = 0.005
TOL = 0.05
HOLD = RodHold(GEOM, HOLES, AXIS, SIG, 24, 2 * math.pi, TOL)


def test_prediction_matches_the_spread_of_simulated_holds():
    """30 holds at the plan's poses (24 equally spaced, 5 um pose means): the SD of each solved
    diameter is the predicted u(D) within 30 % (the SD of 30 draws scatters by 13 %).
    """
    pred = np.array(predict_rod(HOLD).u_diameter_mm)
    alpha = np.linspace(0.0, 2 * math.pi, 24, endpoint=False)
    v0 = rod_readings(alpha, list(GEOM), list(HOLES), AXIS)
    rng = np.random.default_rng(3)
    d = np.array(
        [
            solve_rod(
                v0 + SIG * rng.standard_normal(v0.shape), layers=GEOM, u_reading_mm=SIG, coaxiality_mm=TOL
            ).diameter_mm
            for _ in range(30)
        ]
    )
    ratio = d.std(axis=0, ddof=1) / pred
    assert np.all((ratio > 0.7) & (ratio < 1.3)), ratio


def test_hold_of_a_noiseless_solve_reproduces_the_bound_at_the_truth():
    """The hold a solve describes (its frame: axis through the origin, centres plus the axis offset)
    gives the bound at the truth within 2 %.
    """
    alpha = np.linspace(0.0, 2 * math.pi, 24, endpoint=False)
    v = rod_readings(alpha, list(GEOM), list(HOLES), AXIS)
    sol = solve_rod(v, layers=GEOM, u_reading_mm=SIG, coaxiality_mm=TOL)
    hold = hold_of_solution(sol, TOL)
    assert hold.n_poses == 24 and abs(hold.spread_rad - 2 * math.pi * 23 / 24) < 1e-9
    truth = 2 * rod_crb(alpha, layers=GEOM, holes=HOLES, axis=AXIS, sigma_mm=SIG, coaxiality_mm=TOL)
    planned = np.array(predict_rod(replace(hold, spread_rad=2 * math.pi)).u_diameter_mm)
    np.testing.assert_allclose(planned, truth, rtol=0.02)


def test_recommendation_is_the_fewest_poses_reaching_the_target():
    """Over the full circle, the chosen number of poses reaches the target and the one before it does
    not; a target below what 256 poses give is answered with None.
    """
    grid = (8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256)
    target = 0.75 * predict_rod(HOLD).u_diameter_mm[1]
    for spread, best in recommend_rod(HOLD, target, grid, (2 * math.pi,)):
        assert best is not None
        assert max(best.u_diameter_mm) <= target
        i = grid.index(best.hold.n_poses)
        if i > 0:
            before = predict_rod(replace(HOLD, n_poses=grid[i - 1], spread_rad=spread))
            assert max(before.u_diameter_mm) > target
    tiny = 0.5 * max(predict_rod(replace(HOLD, n_poses=256)).u_diameter_mm)
    assert all(best is None for _, best in recommend_rod(HOLD, tiny, grid, (2 * math.pi,)))


def test_plan_command_for_a_rod_hold(tmp_path, capsys):
    """``borescan plan --rod-scan``: the hold's u(D) as solved and as planned, per spread the fewest
    poses for the target (exit 0 when one reaches it); a missing folder is a usage error (exit 2).
    """
    from borescan.cli import main
    from borescan.synthetic.scenes import RodScene
    from borescan.synthetic.simulate import simulate_rod, write_simulated

    scene = RodScene(layers=GEOM, holes=HOLES, axis=AXIS, range_mm=(8.0, 8.0), sample_rate_hz=100.0)
    art = {
        "id": "P",
        "type": "part",
        "features": [
            {"id": f"H{j + 1}", "z_mm": lay.h_mm, "nominal_diameter_mm": 150.0} for j, lay in enumerate(GEOM)
        ],
    }
    sim = simulate_rod(
        scene,
        n_poses=24,
        samples_per_pose=5,
        artifact=art,
        features=("H1", "H2"),
        seed=5,
        nominal_layers=GEOM,
        scan_id="PLAN-ROD",
    )
    folder = write_simulated(sim, tmp_path / "raw", tmp_path / "truth")
    assert main(["plan", "--rod-scan", str(folder), "--target-u-d-um", "1000"]) == 0
    out = capsys.readouterr().out
    assert "PLAN-ROD: 24 poses" in out and "over 360 deg: 8 poses give u(D)" in out
    assert main(["plan", "--rod-scan", str(tmp_path / "nonexistent")]) == 2


def test_a_solved_hold_is_planned_at_its_own_poses():
    """Poses at random (20 in 0-330 deg): the plan of the solved hold, at its own pose
    angles, is the bound at the truth for those angles within 2 %; equally spaced over the same
    spread it is another number (what a proposed hold of 20 poses would give).
    """
    alpha = np.sort(np.random.default_rng(5).uniform(0.0, np.deg2rad(330.0), 20))
    alpha -= alpha[0]
    v = rod_readings(alpha, list(GEOM), list(HOLES), AXIS)
    sol = solve_rod(v, layers=GEOM, u_reading_mm=SIG, coaxiality_mm=TOL)
    hold = hold_of_solution(sol, TOL)
    assert np.max(np.abs(np.angle(np.exp(1j * (np.array(hold.alpha_rad) - alpha))))) < 1e-6
    truth = 2 * rod_crb(alpha, layers=GEOM, holes=HOLES, axis=AXIS, sigma_mm=SIG, coaxiality_mm=TOL)
    np.testing.assert_allclose(predict_rod(hold).u_diameter_mm, truth, rtol=0.02)
    even = np.array(predict_rod(replace(hold, alpha_rad=None)).u_diameter_mm)
    assert np.max(np.abs(even / truth - 1)) > 0.05
