"""One cleaning policy for every stage that fits readings (borescan.readings).

Checked against independent computations: the leave-one-out median against a brute-force one,
the static rule against readings with known spikes, and the stages (calibration inputs, static
and rotating measurement, rod pose means) against the same scan simulated without the spikes.
"""

import numpy as np
import pytest

from borescan import readings
from borescan.config import schema_defaults
from borescan.effects import Effect
from borescan.measure import measure_scan
from borescan.rawio import lds_matrix, read_scan
from borescan.readings import (
    CleaningPolicy,
    _median_of_others,
    cleaning_policy,
    prepared_matrix,
    static_spikes,
)
from borescan.rod_calibration import pose_means_of_scan
from borescan.synthetic.scenes import default_tri_scene
from borescan.synthetic.simulate import (
    simulate_rod,
    simulate_tri_spindle,
    simulate_tri_static,
    write_simulated,
)
from borescan.stages.calibration_fit import spindle_inputs

DEFAULT = cleaning_policy(schema_defaults()["signal"])
OFF = CleaningPolicy(spike_threshold_mad=1e9, spike_window_samples=7)


def test_policy_from_config_defaults():
    assert DEFAULT == CleaningPolicy(6.0, 7)


def test_the_signal_stage_takes_the_same_policy():
    from borescan.stages.signal import signal_options

    cfg = {**schema_defaults()["signal"], "spike_threshold_mad": 4.5, "spike_window_samples": 9}
    opts = signal_options(cfg)
    assert (opts["spike_threshold"], opts["spike_window_samples"]) == (4.5, 9)
    assert cleaning_policy(cfg) == CleaningPolicy(4.5, 9)


@pytest.mark.parametrize("n", range(2, 13))
def test_median_of_others_brute_force(n):
    rng = np.random.default_rng(n)
    for x in (rng.normal(size=n), rng.integers(0, 3, n).astype(float)):  # ties too
        want = np.array([np.median(np.delete(x, i)) for i in range(n)])
        assert np.allclose(_median_of_others(x), want, atol=0, rtol=0)


def test_static_rule_finds_spikes_not_pose_steps():
    """30 poses x 5 readings whose levels jump by mm from pose to pose: the 10-sigma spikes are
    found, nothing else (a Hampel test along time would see the steps).
    """
    rng = np.random.default_rng(3)
    sigma, k, n = 0.003, 30, 5
    pose = np.repeat(np.arange(k), n)
    levels = rng.uniform(-4, 4, (k, 2))
    v = levels[pose] + rng.normal(0, sigma, (k * n, 2))
    hit = [(7, 0), (33, 1), (101, 0)]
    for i, j in hit:
        v[i, j] += 10 * sigma * np.sign(rng.normal())
    v[50, 1] = np.nan  # a null is not a spike
    spikes = static_spikes(v, pose, 6.0)
    assert sorted(zip(*np.nonzero(spikes))) == hit
    assert not static_spikes(levels[pose] + rng.normal(0, sigma, (k * n, 2)), pose, 6.0).any()


def _outliers(channel, rate=0.01, size_mm=0.05):
    return Effect("outliers", {"channel": channel, "rate": rate, "size_mm": size_mm})


def test_static_measurement_ignores_spikes(tmp_path):
    """A static three-sensor scan with 1 % spikes of 50 um on channel 2 measures as the same scan
    without them (same seed, same noise) to well within its u; with the policy off it does not.
    """
    scene = default_tri_scene()
    kw = dict(samples_per_pose=40, noise_mm=0.002, seed=11)
    clean = read_scan(
        write_simulated(simulate_tri_static(scene, scan_id="S0", **kw), tmp_path / "raw", tmp_path / "t")
    )
    dirty = read_scan(
        write_simulated(
            simulate_tri_static(scene, scan_id="S1", effects=[_outliers(2)], **kw),
            tmp_path / "raw",
            tmp_path / "t",
        )
    )
    beams = scene.beams
    d0 = measure_scan(clean, beams)["diameter_mm"]
    res = measure_scan(dirty, beams, cleaning=DEFAULT)
    off = measure_scan(dirty, beams, cleaning=OFF)["diameter_mm"]
    assert abs(res["diameter_mm"] - d0) < 0.3 * res["u_diameter_mm"]
    assert abs(off - d0) > 2 * abs(res["diameter_mm"] - d0)
    assert measure_scan(dirty, beams)["diameter_mm"] == res["diameter_mm"]  # None = the schema's policy


def test_spindle_stages_share_the_policy(tmp_path):
    """Calibration inputs and the rotating measurement take the same cleaned readings: the
    configured threshold reaches both (off: every spike kept).
    """
    scene = default_tri_scene()
    sim = simulate_tri_spindle(scene, n_rev=3, scan_id="R1", seed=5, effects=[_outliers(1)])
    scan = read_scan(write_simulated(sim, tmp_path / "raw", tmp_path / "t"))
    raw = lds_matrix(scan).values_mm
    cleaned = prepared_matrix(scan, DEFAULT).values_mm
    set_aside = np.isnan(cleaned) & np.isfinite(raw)
    assert set_aside[:, 0].sum() >= 0.5 * 0.01 * raw.shape[0] and not set_aside[:, 1:].any()
    assert np.array_equal(spindle_inputs(scan, cleaning=DEFAULT).readings_mm, cleaned, equal_nan=True)
    assert np.array_equal(spindle_inputs(scan, cleaning=OFF).readings_mm, raw, equal_nan=True)
    on = measure_scan(scan, scene.beams, cleaning=DEFAULT)["diameter_mm"]
    assert measure_scan(scan, scene.beams, cleaning=OFF)["diameter_mm"] != on


def test_rod_pose_means_ignore_spikes(tmp_path):
    """Rod poses (20 um noise) with 5 % spikes of 0.3 mm on layer 1: the pose means equal those of
    the same scan without them to within the noise of a mean; with the policy off they do not.
    """
    sim_kw = dict(n_poses=12, samples_per_pose=9, seed=4)
    clean = read_scan(
        write_simulated(simulate_rod(scan_id="ROD0", **sim_kw), tmp_path / "raw", tmp_path / "t")
    )
    dirty = read_scan(
        write_simulated(
            simulate_rod(scan_id="ROD1", effects=[_outliers(1, 0.05, 0.3)], **sim_kw),
            tmp_path / "raw",
            tmp_path / "t",
        )
    )
    v = lds_matrix(dirty).values_mm
    spikes = readings.static_spikes(v, lds_matrix(dirty).pose, DEFAULT.spike_threshold_mad)
    _, m0, _, _ = pose_means_of_scan(clean)
    _, m1, _, _ = pose_means_of_scan(dirty, DEFAULT)
    _, moff, _, _ = pose_means_of_scan(dirty, OFF)
    assert spikes[:, 0].sum() >= 2 and not spikes[:, 1:].any()
    assert np.max(np.abs(moff - m0)) > 0.004
    sigma = float(dirty.meta["sensors"][0]["repeatability_mm"])  # the simulated noise, 20 um
    assert np.max(np.abs(m1 - m0)) < 4 * sigma / np.sqrt(8)  # a mean of the 8 readings left
