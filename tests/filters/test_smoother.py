"""The reference smoother (pipeline/filters/smoother.py): the per-axis closed form against
the matrix Kalman filter + RTS recomputed inline, the exact interpolation between
reports, gating and restarts, the IMM's manoeuvre probability, the difference-based
noise estimate, the radial quantile, and a seeded Monte Carlo of the covariance."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.filters import kalman
from pipeline.filters import smoother as sm


def _cv(h: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """4-state CV model [x, y, vx, vy]."""
    F = np.eye(4)
    F[0, 2] = F[1, 3] = h
    Q1 = q * np.array([[h**3 / 3, h**2 / 2], [h**2 / 2, h]])
    Q = np.zeros((4, 4))
    Q[np.ix_([0, 2], [0, 2])] = Q1
    Q[np.ix_([1, 3], [1, 3])] = Q1
    return F, Q


def _matrix_rts(t, z, r, zv, rv, q):
    """Plain matrix KF + RTS of one sequence (FilterPy / textbook form): the reference."""
    n = t.size
    xs_f, Ps_f, xs_p, Ps_p = [], [], [None], [None]
    x = np.r_[z[0], zv[0] if np.isfinite(zv[0, 0]) else [0.0, 0.0]]
    P = np.diag([r[0], r[0], *([rv[0]] * 2 if np.isfinite(zv[0, 0]) else [sm.V0_VAR_M2PS2] * 2)])
    xs_f.append(x)
    Ps_f.append(P)
    for j in range(1, n):
        F, Q = _cv(t[j] - t[j - 1], q[j])
        xp, Pp = kalman.predict(x[None], P[None], F, Q)
        xs_p.append(xp[0])
        Ps_p.append(Pp[0])
        H = np.eye(4)
        R = np.diag([r[j], r[j], rv[j], rv[j]])
        use = np.array([[True, True, *[bool(np.isfinite(zv[j, 0]))] * 2]])
        zz = np.r_[z[j], np.nan_to_num(zv[j])][None]
        x, P, _ = kalman.update_masked(xp, Pp, zz, H, R, use)
        x, P = x[0], P[0]
        xs_f.append(x)
        Ps_f.append(P)
    xs, Ps = [None] * n, [None] * n
    xs[-1], Ps[-1] = xs_f[-1], Ps_f[-1]
    for j in range(n - 2, -1, -1):
        F, _ = _cv(t[j + 1] - t[j], q[j + 1])
        G = Ps_f[j] @ F.T @ np.linalg.inv(Ps_p[j + 1])
        xs[j] = xs_f[j] + G @ (xs[j + 1] - xs_p[j + 1])
        Ps[j] = Ps_f[j] + G @ (Ps[j + 1] - Ps_p[j + 1]) @ G.T
    return np.array(xs), np.array(Ps)


def _sequences(rng, n_targets=5, max_len=40):
    lens = rng.integers(2, max_len, n_targets)
    group = np.repeat(np.arange(n_targets), lens)
    t = np.concatenate([np.cumsum(rng.uniform(2.0, 30.0, k)) for k in lens])
    z = rng.normal(0, 50, (t.size, 2)) + np.c_[3 * t, -2 * t]
    zv = rng.normal([3, -2], 0.3, (t.size, 2))
    zv[rng.random(t.size) < 0.3] = np.nan
    r = rng.uniform(4, 100, t.size)
    rv = rng.uniform(0.01, 1.0, t.size)
    return group, t, z, r, zv, rv


def test_closed_form_rts_equals_the_matrix_filter_and_smoother():
    rng = np.random.default_rng(5)
    group, t, z, r, zv, rv = _sequences(rng)
    pk = sm.pack(group)
    q = pk.grid(rng.uniform(1e-4, 0.5, t.size))
    fit = sm.rts_smooth(pk, pk.grid(t), pk.grid(z), pk.grid(r), pk.grid(zv), pk.grid(rv), q)
    ps, vs, a = pk.flat(fit.ps), pk.flat(fit.vs), pk.flat(fit.as_)
    qf = pk.flat(q)
    for g in np.unique(group):
        i = np.flatnonzero(group == g)
        xs, Ps = _matrix_rts(t[i], z[i], r[i], zv[i], rv[i], qf[i])
        np.testing.assert_allclose(ps[i], xs[:, :2], rtol=1e-9, atol=1e-7)
        np.testing.assert_allclose(vs[i], xs[:, 2:], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(a[i, 0], Ps[:, 0, 0], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(a[i, 1], Ps[:, 1, 1], rtol=1e-9, atol=1e-9)


def test_interpolation_equals_a_report_without_information():
    """The smoothed state at a time between reports equals that of a smoother run with a
    knot there carrying no information (a measurement of infinite variance)."""
    rng = np.random.default_rng(9)
    group, t, z, r, zv, rv = _sequences(rng, n_targets=3, max_len=15)
    pk = sm.pack(group)
    q = np.full(t.size, 0.05)
    fit = sm.rts_smooth(pk, pk.grid(t), pk.grid(z), pk.grid(r), pk.grid(zv), pk.grid(rv),
                        pk.grid(q))
    for g in np.unique(group):
        i = np.flatnonzero(group == g)
        if i.size < 3:
            continue
        k = i.size // 2
        tq = 0.3 * t[i[k]] + 0.7 * t[i[k + 1]]
        row = int(np.flatnonzero(pk.group == g)[0])
        p, v, a, _c = sm.interpolate(fit, np.array([row]), np.array([k]), np.array([tq]))
        # the same with an uninformative knot inserted (matrix path)
        ti = np.insert(t[i], k + 1, tq)
        zi = np.insert(z[i], k + 1, [0.0, 0.0], axis=0)
        ri = np.insert(r[i], k + 1, 1e16)
        zvi = np.insert(zv[i], k + 1, [np.nan, np.nan], axis=0)
        rvi = np.insert(rv[i], k + 1, 1.0)
        xs, Ps = _matrix_rts(ti, zi, ri, zvi, rvi, np.full(ti.size, 0.05))
        np.testing.assert_allclose(p[0], xs[k + 1, :2], rtol=1e-7, atol=1e-5)
        np.testing.assert_allclose(v[0], xs[k + 1, 2:], rtol=1e-7, atol=1e-7)
        np.testing.assert_allclose(a[0], np.diag(Ps[k + 1])[:2], rtol=1e-6)


def _track(rng, t, turn_from=None, turn_rate=0.0, speed=6.0, sigma=3.0):
    """A ship on a straight course, turning at ``turn_rate`` rad/s after ``turn_from``:
    true positions/velocities, noisy AIS-like reports."""
    course = np.where(t < (turn_from or np.inf), 0.3,
                      0.3 + turn_rate * (t - (turn_from or 0.0)))
    dt = np.diff(t, prepend=t[0])
    vx, vy = speed * np.sin(course), speed * np.cos(course)
    x, y = np.cumsum(vx * dt), np.cumsum(vy * dt)
    truth = np.c_[x, y]
    z = truth + rng.normal(0, sigma, truth.shape)
    zv = np.c_[vx, vy] + rng.normal(0, 0.05, truth.shape)
    return truth, np.c_[vx, vy], z, zv


def test_an_isolated_outlier_is_rejected_and_a_jump_restarts():
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 600.0, 10.0)
    _, _, z, zv = _track(rng, t)
    z[20] += [400.0, 0.0]          # one bad report
    z[40:] += [0.0, 800.0]         # the target jumps (another transponder)
    pk = sm.pack(np.zeros(t.size, int))
    r = np.full(t.size, 9.0)
    rv = np.full(t.size, 0.1)
    res = sm.imm_forward(pk, pk.grid(t), pk.grid(z), pk.grid(r), pk.grid(zv), pk.grid(rv),
                         sm.MotionModel())
    acc, restart = pk.flat(res.accepted), pk.flat(res.restart)
    assert not acc[20] and acc[21]
    assert restart[0] and restart[42] and restart.sum() == 2
    assert not acc[40] and not acc[41] and acc[42:].all()
    assert acc[:20].all() and acc[21:40].all()


def test_the_manoeuvre_probability_marks_the_turn():
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 1200.0, 10.0 / 3.0)
    turn = (t >= 500) & (t < 600)
    truth, _, z, zv = _track(rng, t, turn_from=500.0, turn_rate=np.radians(1.5))
    # the turn ends at 600 s: straight again
    course_end = 0.3 + np.radians(1.5) * 100.0
    after = t >= 600
    v = 6.0 * np.c_[np.sin(course_end), np.cos(course_end)]
    truth[after] = truth[np.flatnonzero(after)[0] - 1] + (t[after] - t[after][0] + t[1] - t[0]
                                                           )[:, None] * v
    z[after] = truth[after] + rng.normal(0, 3.0, (after.sum(), 2))
    zv[after] = v + rng.normal(0, 0.05, (after.sum(), 2))
    pk = sm.pack(np.zeros(t.size, int))
    args = (pk.grid(t), pk.grid(z), pk.grid(np.full(t.size, 9.0)), pk.grid(zv),
            pk.grid(np.full(t.size, 0.01)))
    mu = pk.flat(sm.manoeuvre_probability(pk, *args, sm.MotionModel()))
    assert mu[turn].mean() > 0.8
    assert mu[(t < 400) | (t > 800)].mean() < 0.2


def test_the_difference_estimate_recovers_the_noise_of_straight_tracks():
    rng = np.random.default_rng(8)
    sig = np.array([2.0, 5.0, 12.0])
    groups, ts, zs = [], [], []
    for g, s in enumerate(sig):
        t = np.cumsum(rng.uniform(2, 12, 300))
        _, _, z, _ = _track(rng, t, sigma=s)
        groups.append(np.full(t.size, g))
        ts.append(t)
        zs.append(z)
    pk = sm.pack(np.concatenate(groups))
    r = sm.difference_variance(pk, pk.grid(np.concatenate(ts)), pk.grid(np.concatenate(zs)))
    est = np.sqrt(r[np.argsort(pk.group)])
    np.testing.assert_allclose(est, sig, rtol=0.1)


@pytest.mark.parametrize("rho", [1.0, 0.5, 0.1, 0.0])
def test_radial_p95_against_sampling(rho):
    rng = np.random.default_rng(2)
    e = rng.normal(size=(400_000, 2)) * [1.0, rho]
    got = sm.radial_p95(np.array([4.0]), np.array([4.0 * rho**2]))[0]
    assert abs(got - 2.0 * np.quantile(np.hypot(*e.T), 0.95)) < 0.02


def test_rotated_covariance_has_the_same_radial_p95():
    a = sm.radial_p95(np.array([9.0]), np.array([1.0]))
    th = 0.7
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    C = R @ np.diag([9.0, 1.0]) @ R.T
    b = sm.radial_p95(np.array([C[0, 0]]), np.array([C[1, 1]]), np.array([C[0, 1]]))
    np.testing.assert_allclose(a, b, rtol=1e-9)


def test_smoothed_covariance_is_honest_monte_carlo():
    """Seeded: ships turning and going straight, AIS-like reports (3 m, 10 s; 3 1/3 s in
    turns), the reference at 1-s query times between the reports: NEES of the
    interpolated position near 2 and the own 95 % radius holding ~95 % of the errors."""
    rng = np.random.default_rng(11)
    model = sm.MotionModel()
    nees, inside = [], []
    for _ in range(20):
        t = np.sort(np.r_[np.arange(0.0, 300.0, 10.0), np.arange(300.0, 420.0, 10.0 / 3),
                          np.arange(420.0, 900.0, 10.0)]) + rng.uniform(0, 2)
        truth_rate = np.radians(rng.uniform(0.3, 2.0)) * rng.choice([-1, 1])
        tq = np.arange(t[0], t[-1], 1.0)
        allt = np.union1d(t, tq)
        truth, _, z_all, zv_all = _track(rng, allt, turn_from=300.0, turn_rate=truth_rate)
        at = np.isin(allt, t)
        z, zv = z_all[at], zv_all[at]
        # the turn stops at 420 s: keep it simple, evaluate up to the end anyway
        pk = sm.pack(np.zeros(t.size, int))
        g = (pk.grid(t), pk.grid(z), pk.grid(np.full(t.size, 9.0)), pk.grid(zv),
             pk.grid(np.full(t.size, 0.0025)))
        mu = sm.lookahead_max(sm.imm_forward(pk, *g, model).mu_high, 3)
        mu_int = np.fmax(mu, np.c_[mu[:, :1], mu[:, :-1]])
        q = model.q_low + mu_int * (model.q_high - model.q_low)
        fit = sm.rts_smooth(pk, *g, q)
        col = np.searchsorted(t, tq, "right") - 1
        p, _, a, _ = sm.interpolate(fit, np.zeros(tq.size, np.int64), col, tq)
        e = p - truth[np.isin(allt, tq)]
        nees.append((e * e / a).sum(axis=1))
        inside.append(np.hypot(*e.T) <= sm.radial_p95(a[:, 0], a[:, 1]))
    nees, inside = np.concatenate(nees), np.concatenate(inside)
    assert 1.4 < nees.mean() < 2.6, nees.mean()
    assert 0.9 < inside.mean() < 0.99, inside.mean()
