from ssr.baselines import NSRRModel, RAEModel
from ssr.flops import measured_flops_per_pixel
from ssr.model import SSRConfig, SSRModel, flops_per_pixel


def test_measured_ssr_cost_equals_the_analytic_count():
    # The shipped model's options too: they read buffers beyond data.BUFFERS (the footprint
    # albedo, the directly seen emission, the samples' escapes), which the count must feed.
    shipped = dict(albedo="footprint", emission="background", mean_correction="atrous")
    for cfg in (
        SSRConfig(),
        SSRConfig(enc=(8, 12, 16), tfa_hidden=4, k=4),
        SSRConfig(**shipped),
        SSRConfig(enc=(16, 32, 28, 24), **shipped),
        SSRConfig(escaped="background", **shipped),
    ):
        want, _ = flops_per_pixel(cfg)
        got = measured_flops_per_pixel(SSRModel(cfg).eval(), 32, 32)
        assert abs(got - want) <= 1e-6 * want, (cfg, got, want)


def test_baselines_cost_more_than_ssr():
    ssr, _ = flops_per_pixel(SSRConfig())
    for m in (RAEModel(), NSRRModel()):
        f = measured_flops_per_pixel(m.eval(), 32, 32)
        assert f > ssr, (type(m).__name__, f)
