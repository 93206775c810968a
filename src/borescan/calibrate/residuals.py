"""Residuals and analytic Jacobian of the full-data calibration, and its least-squares solves.

The readings are the device model's (:mod:`borescan.physics.tri`): its step 5 on the ring gauge
(:func:`~borescan.physics.tri.tri_readings_at`, the step :func:`~borescan.physics.tri.tri_forward`
takes) and its analytic derivatives (:func:`~borescan.physics.tri.tri_spindle_jacobian`) at the
device angle of the commanded kinematics with ``speed_error`` of the registry
(:func:`~borescan.physics.tri.commanded_device_angle`); channel delays are in the commanded angle of
each reading (step 1, taken once by :mod:`borescan.calibrate.starts`). Rows: per
scan the valid readings sample by sample, channel by channel, then the prior rows
w (o - o_reported) of the scans with a reported offset. The solves' iterations take J^T J and J^T f
channel by channel (:func:`normal_equations`) instead of the whole J and its QR.
"""

from __future__ import annotations

import numpy as np

from borescan.calibrate.problem import FullProblem, ScanNuisance
from borescan.geometry import Beams, Bore
from borescan.levmar import LMResult, levenberg_marquardt
from borescan.physics.tri import commanded_device_angle, tri_readings_at, tri_spindle_jacobian
from borescan.physics.tri_params import dbeta_drho_at_psi, dd_b_drho_at_g

__all__ = [
    "device_angles",
    "model_readings",
    "residuals",
    "residuals_and_jacobian",
    "normal_equations",
    "solve",
    "solve_fixed",
    "block_rows",
]


def device_angles(pb: FullProblem, k: int, nu: ScanNuisance) -> np.ndarray:
    """Return the device angle of each reading of scan ``k``, (n, 1) or (n, c) [rad]."""
    a = pb.commanded_rad[k]
    return commanded_device_angle(a, nu.phase_rad, nu.speed_scale) if pb.commanded[k] else a


def model_readings(pb: FullProblem, beams: Beams, k: int, nu: ScanNuisance, sel=slice(None)) -> np.ndarray:
    """Return the model's readings (n, c) of scan ``k`` (rows ``sel``) [mm]: the gauge at the origin."""
    return tri_readings_at(device_angles(pb, k, nu)[sel], nu.offset_mm, beams, Bore((0.0, 0.0), pb.R_mm))


def _prior_rows(pb: FullProblem, nuis: list[ScanNuisance]) -> list[np.ndarray]:
    return [pb.prior_w * (nu.offset_mm - p) for nu, p in zip(nuis, pb.priors) if p is not None]


def residuals(pb: FullProblem, x: np.ndarray, rows: list | None = None) -> np.ndarray:
    """Return model - readings of the used readings, then the prior rows, at internal vector ``x``.

    ``rows``: per scan the samples to use (a slice), None for all.
    """
    beams, nuis = pb.unpack(x)
    parts, readings = [], []
    for k, nu in enumerate(nuis):
        sel = slice(None) if rows is None else rows[k]
        v = model_readings(pb, beams, k, nu, sel)
        readings.append(v)
        parts.append((v - pb.ys[k][sel])[pb.masks[k][sel]])
    if rows is None:  # the iteration asks for J^T J where it has just evaluated the residuals
        pb.row_cache["readings"] = (np.asarray(x, dtype=float).tobytes(), readings)
    return np.concatenate(parts + _prior_rows(pb, nuis))


def residuals_and_jacobian(
    pb: FullProblem, x: np.ndarray, rows: list | None = None, full: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Return the residuals (:func:`residuals`) and their analytic Jacobian in the internal parameters.

    ``full``: 1 + K columns more, d/d beta of the first channel and d/d phase of each scan (all
    free: the rank of the gauge). The Jacobian is filled column by column into its transpose
    (ncols, rows) and returned as J = JT.T, Fortran-ordered, the layout MINPACK works in.
    """
    beams, nuis = pb.unpack(x)
    blocks, parts = [], []
    for k, nu in enumerate(nuis):
        sel = slice(None) if rows is None else rows[k]
        v, jac = tri_spindle_jacobian(device_angles(pb, k, nu)[sel], beams, nu.offset_mm, pb.R_mm)
        blocks.append((k, sel, jac))
        parts.append((v - pb.ys[k][sel])[pb.masks[k][sel]])
    r = np.concatenate(parts + _prior_rows(pb, nuis))
    JT = np.zeros((pb.n_params + (1 + pb.K if full else 0), r.size))
    b0 = 0
    for k, sel, jac in blocks:
        b0 = _fill_scan_block(pb, JT, b0, k, sel, jac, beams.rho_mm, full)
    for k, p in enumerate(pb.priors):
        if p is not None:
            JT[pb.cols[k].ox, b0] = pb.prior_w
            JT[pb.cols[k].oy, b0 + 1] = pb.prior_w
            b0 += 2
    return r, JT.T


def _kept(normal: tuple[np.ndarray, np.ndarray], keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """J^T J and J^T f of the Jacobian's columns ``keep``."""
    JtJ, Jtf = normal
    return JtJ[np.ix_(keep, keep)], Jtf[keep]


def block_rows(pb: FullProblem, k: int, sel: slice, b0: int) -> tuple[int, list[np.ndarray]]:
    """Return scan ``k``'s valid readings (rows ``sel``) and each channel's rows of the Jacobian from ``b0``.

    The rows are sample by sample, channel by channel; they depend on the mask only, so they are
    computed once per problem and block (``pb.row_cache``), not at every Jacobian.
    """
    key = (k, sel.start, sel.stop, sel.step, b0)
    hit = pb.row_cache.get(key)
    if hit is None:
        m = pb.masks[k][sel]
        at = (np.cumsum(m.ravel()) - 1).reshape(m.shape)  # row of each valid reading in the block
        hit = (int(m.sum()), [b0 + at[m[:, j], j] for j in range(pb.c)])
        pb.row_cache[key] = hit
    return hit


def _fill_scan_block(
    pb: FullProblem, JT, b0: int, k: int, sel, jac: dict, rho: np.ndarray, full: bool
) -> int:
    """Fill scan ``k``'s rows (from ``b0``) of the transposed Jacobian; return the next row."""
    n_k, rows_of = block_rows(pb, k, sel, b0)
    samples = _channel_samples(pb, k, sel)
    for j in range(pb.c):
        idx, A = _channel_block(pb, k, sel, j, samples[j], jac, rho)
        for i, col in enumerate(idx):
            JT[col, rows_of[j]] = A[:, i]
        if full:
            if j == 0 and not pb.ch0_free:
                JT[pb.n_params, rows_of[0]] = np.take(jac["beta"][0], samples[0])
            JT[pb.n_params + 1 + k, rows_of[j]] = np.take(jac["phi"][j], samples[j])
    return b0 + n_k


def _channel_block(
    pb: FullProblem, k: int, sel, j: int, at: np.ndarray, jac: dict, rho: np.ndarray, extra: int = 0
) -> tuple[list[int], np.ndarray]:
    """Return the parameters a valid reading of channel ``j`` of scan ``k`` depends on, and its derivatives.

    The derivatives at the samples ``at``, Fortran-ordered, one column per parameter and ``extra``
    columns more left for the caller: d/dbeta_j (beta free), d/drho_j at fixed psi and g (beta moves by
    dbeta_drho, d_b by dd_b_drho: v = s - d_b), d/dg_j = -1, the offset's, the phase's and the speed
    scale's. The one place :func:`_fill_scan_block` and :func:`_add_scan_products` take them from.
    """
    cl = pb.cols[k]
    beta_free = pb.beta_free(j)
    idx = ([j - 1 + pb.ch0_free] if beta_free else []) + [pb.i_rho0 + j, pb.i_g0 + j, cl.ox, cl.oy]
    idx += [i for i in (cl.phase, cl.scale) if i is not None]
    A = np.empty((at.size, len(idx) + extra), order="F")
    i_rho = int(beta_free)
    np.take(jac["rho"][j], at, out=A[:, i_rho])
    A[:, i_rho] -= dd_b_drho_at_g(rho, pb.R_mm)[j]
    if beta_free:
        np.take(jac["beta"][j], at, out=A[:, 0])
        A[:, i_rho] += A[:, 0] * dbeta_drho_at_psi(rho, pb.R_mm)[j]
    A[:, i_rho + 1] = -1.0
    np.take(jac["ox"][j], at, out=A[:, i_rho + 2])
    np.take(jac["oy"][j], at, out=A[:, i_rho + 3])
    if cl.phase is not None or cl.scale is not None:
        dphi = np.take(jac["phi"][j], at)
        if cl.phase is not None:
            A[:, i_rho + 4] = dphi
        if cl.scale is not None:
            cmd = pb.commanded_rad[k][sel]
            A[:, len(idx) - 1] = dphi * np.take(cmd[:, j if cmd.shape[1] > 1 else 0], at)
    return idx, A


def normal_equations(
    pb: FullProblem, x: np.ndarray, f: np.ndarray, rows: list | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Return J^T J and J^T f of :func:`residuals_and_jacobian`'s J at ``x``, without forming J.

    ``f``: the residuals at ``x`` (:func:`residuals`, same ``rows``). A reading of channel j of scan
    k has at most seven non-zero derivatives (beta_j, rho_j, g_j, the scan's offset, phase and speed
    scale), so each channel's readings are gathered with those columns and ``f`` into one narrow
    block and its products added in (a prior row has one). The same sums as J^T J of the whole
    Jacobian, in another order: equal to rounding (``tests/test_calibrate_model.py``).
    """
    beams, nuis = pb.unpack(x)
    n = pb.n_params
    G = np.zeros((n + 1, n + 1))  # [J f]^T [J f]; its last row and column hold J^T f
    b0 = 0
    known = pb.row_cache.get("readings")
    if rows is not None or known is None or known[0] != np.asarray(x, dtype=float).tobytes():
        known = None  # the readings at x, when :func:`residuals` has just computed them
    for k, nu in enumerate(nuis):
        sel = slice(None) if rows is None else rows[k]
        v_cn = None if known is None else known[1][k].T
        _, jac = tri_spindle_jacobian(
            device_angles(pb, k, nu)[sel], beams, nu.offset_mm, pb.R_mm, readings_cn=v_cn
        )
        b0 = _add_scan_products(pb, G, f, b0, k, sel, jac, beams.rho_mm)
    for k, p in enumerate(pb.priors):
        if p is not None:
            cl = pb.cols[k]
            for i, col in enumerate((cl.ox, cl.oy)):
                G[col, col] += pb.prior_w**2
                G[col, n] += pb.prior_w * f[b0 + i]
            b0 += 2
    return G[:n, :n], G[:n, n]


def _add_scan_products(
    pb: FullProblem, G: np.ndarray, f: np.ndarray, b0: int, k: int, sel, jac: dict, rho: np.ndarray
) -> int:
    """Add scan ``k``'s rows (from ``b0``) to [J f]^T [J f] (:func:`normal_equations`); return the next row.

    Channel j's block holds, per valid reading, its derivatives (:func:`_channel_block`, the ones
    :func:`_fill_scan_block` writes) and its residual.
    """
    n_k, rows_of = block_rows(pb, k, sel, b0)
    samples = _channel_samples(pb, k, sel)
    for j in range(pb.c):
        idx, A = _channel_block(pb, k, sel, j, samples[j], jac, rho, extra=1)
        np.take(f, rows_of[j], out=A[:, -1])
        idx = idx + [pb.n_params]
        G[np.ix_(idx, idx)] += A.T @ A
    return b0 + n_k


def _channel_samples(pb: FullProblem, k: int, sel: slice) -> list[np.ndarray]:
    """Return per channel the samples (rows ``sel`` of scan ``k``) with a valid reading (cached)."""
    key = ("samples", k, sel.start, sel.stop, sel.step)
    hit = pb.row_cache.get(key)
    if hit is None:
        m = pb.masks[k][sel]
        hit = pb.row_cache[key] = [np.flatnonzero(m[:, j]) for j in range(pb.c)]
    return hit


def solve(
    pb: FullProblem, x_start: np.ndarray, rows: list | None = None, nfev: int | None = None
) -> LMResult:
    """Least-squares minimum from ``x_start`` (MINPACK's Levenberg-Marquardt, analytic Jacobian).

    An iteration takes its triangular factor from the normal equations where the scaled Jacobian is
    well conditioned (:func:`normal_equations`, :func:`borescan.levmar.triangle_of_normal_equations`).
    """
    return levenberg_marquardt(
        lambda x: residuals(pb, x, rows=rows),
        x_start,
        lambda x: residuals_and_jacobian(pb, x, rows=rows)[1],
        max_nfev=pb.max_nfev if nfev is None else nfev,
        xtol=1e-10,
        ftol=1e-10,
        gtol=1e-10,
        normal=lambda x, f: normal_equations(pb, x, f, rows=rows),
    )


def solve_fixed(
    pb: FullProblem, x_start: np.ndarray, i_fix: int, nfev: int = 30
) -> tuple[np.ndarray, float, bool]:
    """Minimum of the cost over every internal parameter but ``i_fix`` (held at ``x_start[i_fix]``).

    Returns (internal vector, cost, converged to a finite cost).
    """
    keep = np.arange(pb.n_params) != i_fix
    base = np.array(x_start, dtype=float)

    def full(z: np.ndarray) -> np.ndarray:
        x = base.copy()
        x[keep] = z
        return x

    with np.errstate(all="ignore"):
        res = levenberg_marquardt(
            lambda z: residuals(pb, full(z)),
            base[keep],
            lambda z: residuals_and_jacobian(pb, full(z))[1].T[keep].T,
            max_nfev=nfev,
            xtol=1e-10,
            ftol=1e-10,
            gtol=1e-10,
            jac_at_solution=False,
            normal=lambda z, f: _kept(normal_equations(pb, full(z), f), keep),
        )
    return full(res.x), float(res.cost), bool(res.success) and bool(np.isfinite(res.cost))
