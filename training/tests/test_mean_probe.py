import numpy as np

from ssr.mean_probe import block_sums, correct, upsample


def quarter_mask(h, w, dx=0, dy=0):
    m = np.zeros((h, w, 1))
    m[dy::2, dx::2] = 1.0
    return m


def test_a_uniform_bias_is_removed_and_the_scale_is_clamped():
    h, w = 20, 24
    pred = np.full((h, w, 3), 1.0)
    m = quarter_mask(h, w)
    out, _ = correct([pred], [1.5 * m * np.ones((h, w, 3))], [m], block=8)
    assert np.allclose(out, 1.5)
    out, _ = correct([pred], [10.0 * m * np.ones((h, w, 3))], [m], block=8)
    assert np.allclose(out, 2.0)
    # nothing traced and nothing predicted: unchanged
    out, _ = correct([np.zeros((h, w, 3))], [np.zeros((h, w, 3))], [m], block=8)
    assert np.allclose(out, 0.0)


def test_tiles_sum_and_interpolate():
    x = np.arange(5 * 6 * 2, dtype=np.float64).reshape(5, 6, 2)
    s = block_sums(x, 4)
    assert s.shape == (2, 2, 2) and np.isclose(s.sum(), x.sum())
    assert np.allclose(s[0, 0], x[:4, :4].sum(axis=(0, 1)))
    c = np.array([[[1.0], [3.0]]])  # one row of two tiles
    u = upsample(c, 4, 4, 8)
    assert np.allclose(u[:, :2, 0], 1.0) and np.allclose(u[:, 6:, 0], 3.0)
    assert np.allclose(u[0, 2:6, 0], [1.25, 1.75, 2.25, 2.75])
