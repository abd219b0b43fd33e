"""The compiled transition (_particle.c) against the numpy reference: the same particles,
to the last bit, with and without turns, per-filter and zero time steps, and speeds
at the cap."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.filters import particle as pf

pytestmark = pytest.mark.skipif(pf._particle is None,
                                reason="built without a C compiler: no _particle extension")


def _particles(rng: np.random.Generator, G: int, N: int) -> np.ndarray:
    return np.stack([rng.normal(0.0, 5e3, (G, N)), rng.normal(0.0, 5e3, (G, N)),
                     rng.uniform(0.0, 26.0, (G, N)), rng.uniform(-1.0, 7.3, (G, N))], axis=-1)


@pytest.mark.parametrize("noise", [
    pf.MotionNoise(0.01, 0.05),
    pf.MotionNoise(0.02, 0.3, max_speed_mps=12.0, turn_rate_per_s=0.01, turn_sigma_rad=0.8),
    pf.MotionNoise(0.0, 0.0, turn_rate_per_s=1e6, turn_sigma_rad=1.5),
])
def test_the_compiled_transition_equals_the_numpy_one(noise, monkeypatch) -> None:
    rng = np.random.default_rng(3)
    x = _particles(rng, 7, 501)
    dt = np.array([0.0, 1.0, 3.0, 10.0, 60.0, 600.0, 3600.0])
    compiled = pf.propagate_speed_course(x, dt, noise, np.random.default_rng(9))
    monkeypatch.setattr(pf, "_particle", None)
    reference = pf.propagate_speed_course(x, dt, noise, np.random.default_rng(9))
    np.testing.assert_array_equal(compiled, reference)
    # dt = 0: the position stays, the speed is capped, the course wrapped into [0, 2 pi)
    np.testing.assert_array_equal(compiled[0, :, :2], x[0, :, :2])
    np.testing.assert_array_equal(compiled[0, :, 2], np.minimum(x[0, :, 2], noise.max_speed_mps))
    np.testing.assert_allclose(compiled[0, :, 3], np.mod(x[0, :, 3], 2 * np.pi), atol=1e-12)


def test_a_scalar_step_and_a_strided_batch_give_the_numpy_particles(monkeypatch) -> None:
    rng = np.random.default_rng(4)
    x = _particles(rng, 10, 300)[::2]  # not contiguous: the wrapper copies
    noise = pf.MotionNoise(0.01, 0.05, turn_rate_per_s=0.002, turn_sigma_rad=0.5)
    compiled = pf.propagate_speed_course(x, 30.0, noise, np.random.default_rng(5))
    monkeypatch.setattr(pf, "_particle", None)
    np.testing.assert_array_equal(
        compiled, pf.propagate_speed_course(x, 30.0, noise, np.random.default_rng(5)))


def test_glibc_sincos_gives_numpys_sin_and_cos() -> None:
    """_particle.c takes sin and cos of the mean course from one sincos() call where the
    reference calls numpy's float64 sin and cos ufuncs (libm's, element by element)."""
    rng = np.random.default_rng(2)
    x = np.r_[rng.uniform(-7.0, 14.0, 20_000), rng.normal(0.0, 1e3, 2_000)]
    np.testing.assert_array_equal(np.sin(x), np.array([math.sin(v) for v in x.tolist()]))
    np.testing.assert_array_equal(np.cos(x), np.array([math.cos(v) for v in x.tolist()]))
