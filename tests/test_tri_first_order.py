"""Readings to first order in a change of the bore and the spindle axis, against the exact solve.

:mod:`borescan.physics.tri_first_order` moves exact readings by the implicit derivative of the wall
condition; the linear screen of the examinations takes its bore and spindle-position columns from it
(:mod:`borescan.discrepancy.tri_screen`). Checked: no change gives the exact readings bit for bit; a
change of size delta gives the exact readings to O(delta^2) (the error falls 100-fold when delta falls
10-fold, so the first-order term is right, not merely small); the screen's columns agree with the exact
forward differences to the step's own curvature; the spindle axis computed once per sample is the one
computed per channel. Geometry drawn over the three-sensor contract (bore radius 75-200 mm, spindle
offset 0.5-3 mm, beam offsets up to 15 mm) and beyond it (a 20 mm ring gauge as the demo's).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from borescan.effects import Effect, sort_effects
from borescan.geometry import Beams, Bore, tri_spindle_readings
from borescan.physics.tri import TriBase, spindle_positions
from borescan.physics.tri_first_order import tri_readings_first_order, tri_wall_points
from borescan.synthetic.contract import TRI_CONTRACT, draw_beam_directions, reading_span_mm


def _geometry(seed: int):
    """Return a bore, spindle axis and beams: the contract's ranges, the radius also below them (to 20 mm)."""
    rng = np.random.default_rng(seed)
    R = float(rng.uniform(20.0, TRI_CONTRACT["bore_radius_mm"][1]))
    C = rng.uniform(*TRI_CONTRACT["center_xy_mm"], 2)
    ecc, ang = float(rng.uniform(*TRI_CONTRACT["spindle_offset_mm"])), float(rng.uniform(0, 2 * math.pi))
    o = ecc * np.array([math.cos(ang), math.sin(ang)])
    beta = draw_beam_directions(rng, 3)
    rho = rng.uniform(-1.0, 1.0, 3) * min(TRI_CONTRACT["rho_max_mm"], 0.5 * R)
    d_b = reading_span_mm(beta, rho, o, R).min(axis=0) - 1.0
    shaped = seed % 2 == 1  # every other bore already tilted and lobed (a seed effect of the screen)
    bore = Bore(
        (float(C[0]), float(C[1])),
        R,
        tilt_rad=0.03 if shaped else 0.0,
        tilt_azimuth_rad=0.7 if shaped else 0.0,
        lobes=((3, 0.004, 0.2),) if shaped else (),
    )
    n = 1500
    phi = np.linspace(0.0, 4 * math.pi, n)[:, None] + 0.3
    S = C + o + 1e-3 * np.c_[np.sin(np.arange(n) / 50.0), np.cos(np.arange(n) / 70.0)]  # a spindle stream
    return phi, S, Beams((1, 2, 3), beta, rho, d_b), bore


def _changes(bore: Bore, S: np.ndarray, phi: np.ndarray, delta: float):
    """Return (name, new spindle axis or None, new bore or None) of changes of size ``delta`` [mm]."""
    long_axis = bore.radius_mm / math.cos(bore.tilt_rad) + delta  # the ellipse's long semi-axis, delta longer
    motion = delta * np.stack([np.cos(3 * phi + 0.5), np.sin(3 * phi + 0.5)], axis=-1)  # (n, 1, 2)
    cx, cy = bore.center_xy_mm
    azimuth = bore.tilt_azimuth_rad if bore.tilt_rad else 0.4
    return [
        ("lobing", None, replace(bore, lobes=bore.lobes + ((5, delta, 0.9),))),
        (
            "tilt",
            None,
            replace(bore, tilt_rad=math.acos(bore.radius_mm / long_axis), tilt_azimuth_rad=azimuth),
        ),
        ("thermal", None, replace(bore, radius_mm=bore.radius_mm + delta)),
        ("centre", None, replace(bore, center_xy_mm=(cx + delta, cy - delta))),
        ("error motion", S[:, None, :] + motion, None),
    ]


@pytest.mark.parametrize("seed", range(8))
def test_no_change_gives_the_exact_readings_bit_for_bit(seed):
    phi, S, beams, bore = _geometry(seed)
    v = tri_spindle_readings(phi, S, beams, bore)
    wall = tri_wall_points(phi, S, beams, bore, v)
    assert np.array_equal(tri_readings_first_order(wall), v)
    assert np.array_equal(tri_readings_first_order(wall, S, bore), v)


@pytest.mark.parametrize("seed", range(8))
def test_first_order_readings_are_the_exact_solve_to_second_order(seed):
    """|first order - exact| <= 1e-3 |change| at delta = 10 um, and falls ~100x with delta / 10."""
    phi, S, beams, bore = _geometry(seed)
    v = tri_spindle_readings(phi, S, beams, bore)
    wall = tri_wall_points(phi, S, beams, bore, v)
    for (name, S1, b1), (_, S2, b2) in zip(_changes(bore, S, phi, 1e-2), _changes(bore, S, phi, 1e-3)):
        errs = []
        for Sx, bx in ((S1, b1), (S2, b2)):
            exact = tri_spindle_readings(phi, S if Sx is None else Sx, beams, bore if bx is None else bx)
            change = np.max(np.abs(exact - v))
            err = np.max(np.abs(tri_readings_first_order(wall, Sx, bx) - exact))
            assert change > 0.0, name
            errs.append((err, change))
        (e1, c1), (e2, c2) = errs
        assert e1 <= 1e-3 * c1, (name, e1, c1)
        # second order: 100x smaller for a 10x smaller change (rounding ~1e-15 of the ~mm readings aside)
        assert e2 <= e1 / 50.0 + 1e-12, (name, e1, e2)


def test_the_spindle_axis_once_per_sample_is_the_one_per_channel():
    """The error motion computed once per sample is the one computed per channel, bit for bit.

    With every channel at the sample's angle the axis is (n, 1, 2); broadcast over the channels it is the
    axis computed per channel, and so are the readings.
    """
    phi, S, beams, bore = _geometry(0)
    base = TriBase(beams, bore, S, lambda t: t)
    st = sort_effects(
        [
            Effect("spindle_error_motion", {"k": 3, "rho_mm": 0.004, "phase": 0.3}),
            Effect("spindle_error_motion", {"k": 5, "rho_mm": 0.001, "phase": 1.1}),
        ],
        "tri_lds",
        beams.channels,
    )["spindle_position"]
    once = spindle_positions(base, phi, st)
    per_channel = spindle_positions(base, np.repeat(phi, 3, axis=1), st)
    assert once.shape == (phi.shape[0], 1, 2) and per_channel.shape == (phi.shape[0], 3, 2)
    assert np.array_equal(np.broadcast_to(once, per_channel.shape), per_channel)
    v_once, v_per_channel = (tri_spindle_readings(phi, x, beams, bore) for x in (once, per_channel))
    assert np.array_equal(v_once, v_per_channel)


def test_the_screens_bore_and_spindle_columns_are_the_exact_differences_to_their_curvature():
    """The linear screen's columns of every candidate are the exact differences, to the step's curvature.

    The bore and spindle-position terms' columns from first order agree with the exact forward differences
    to 1e-4 of the column (the step's curvature, about step / R); every other term's columns are the exact
    ones bit for bit.
    """
    from borescan.discrepancy.examine import scan_arrays
    from borescan.discrepancy.search import jacobian_columns
    from borescan.discrepancy.tri import TriModel, tri_data_from_arrays
    from borescan.discrepancy.tri_screen import FIRST_ORDER_STAGES
    from borescan.effects import EFFECTS
    from borescan.synthetic.scenes import default_tri_scene
    from borescan.synthetic.simulate import simulate_tri_spindle

    scan = simulate_tri_spindle(
        default_tri_scene(),
        scan_id="T-FO",
        n_rev=4,
        effects=[Effect("bore_lobing", {"k": 3, "a_mm": 0.003, "phase": 0.4})],
        noise_mm=0.0005,
        seed=3,
        encoder=True,
    )
    t_s, ch, vals, _, sp = scan_arrays(scan)
    model = TriModel(tri_data_from_arrays(scan.meta["scan_id"], scan.meta, t_s, vals, ch, sp))
    p0 = model.base_start()
    p0 = {n: p0.get(n, 0.0) for n in model.base_names()}
    seed = []
    r = model.residual(p0, seed)
    first_order_terms = 0
    for t in model.candidate_terms(k_max=8, vibration_f_hz=7.3):
        pt = {**p0, **{n: 0.0 for n in t.names()}}
        if t.effect == "vibration":
            pt["vibration.f_hz"] = 7.3
        names, scales = t.names(), t.scales()
        names, scales = zip(*[(n, s) for n, s in zip(names, scales) if not n.endswith("f_hz")])
        exact = jacobian_columns(model, pt, [t], list(names), list(scales), f0=r)
        linear = jacobian_columns(model, pt, [t], list(names), list(scales), f0=r, about=(p0, seed))
        if EFFECTS[t.effect].stage in FIRST_ORDER_STAGES:
            first_order_terms += 1
            assert np.max(np.abs(linear - exact)) <= 1e-4 * np.max(np.abs(exact)), t.key
        else:
            assert np.array_equal(linear, exact, equal_nan=True), t.key
    assert first_order_terms >= 8  # the lobing orders, the error motion, tilt and thermal expansion
