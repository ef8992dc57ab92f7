"""refine's held-out checks (issue 19): a one-sided 5 % test along the fitted change, whatever the
number of parameters, that never passes an effect which predicts the held-out data worse."""
import numpy as np

from identify.refine.loop import _held_out_refusal


def _passes(e: np.ndarray, d: np.ndarray) -> bool:
    """The check on whitened residuals ``e`` of the null and a prediction change ``d``."""
    held = {"validation": (float(e @ e), float((e - d) @ (e - d)))}
    return not _held_out_refusal(held, {"validation": float(d @ d)}, "validation", "judging")


def test_level_is_five_percent_for_a_null_effect_of_any_size():
    rng = np.random.default_rng(0)
    n, draws = 400, 4000
    for size in (1.0, 1.645, 4.0):  # s: the change's size in noise standard deviations
        d = rng.standard_normal(n)
        d *= size / np.linalg.norm(d)
        rate = np.mean([_passes(rng.standard_normal(n), d) for _ in range(draws)])
        bound = 0.05 + 3 * np.sqrt(0.05 * 0.95 / draws)
        assert rate < bound, (size, rate)
        if size < 3.29:  # where the bar is above 0 the level is reached, not far below it
            assert rate > 0.05 - 3 * np.sqrt(0.05 * 0.95 / draws), (size, rate)


def test_a_real_effect_passes_and_a_worse_prediction_never_does():
    rng = np.random.default_rng(1)
    d = rng.standard_normal(400)
    d *= 4.0 / np.linalg.norm(d)  # s^2 = 16: passes 99 % of the time (the former chi-square bar 94 %)
    passed = np.mean([_passes(rng.standard_normal(400) + d, d) for _ in range(2000)])
    assert passed > 0.97
    e = rng.standard_normal(400)
    big = rng.standard_normal(400)
    big -= (big @ e) / (e @ e) * e
    big *= 10 / np.linalg.norm(big)  # the data follow the change, significantly, but only 40 % of it
    assert not _passes(e + 0.4 * big, big)  # 4 standard deviations along it, yet a worse prediction


def test_held_out_metric_is_not_biased_along_the_change():
    """The checks weigh a held-out prediction change ``d`` in a noise model of the extended model's
    held-out residuals (``_held_out_noise``). The test's alternative noise model, fitted to
    residuals with the candidate's fit removed, under-states the noise along a smooth ``d``: on
    null data the z statistic <We, Wd>/|Wd| then spread far more than 1 (2 null false alarms in 20
    Navion runs of benchmarks/refine_blind.py). Here: its spread in our metric is about 1."""
    from types import SimpleNamespace

    from scipy import signal

    from identify.refine.loop import _held_out_noise

    rng = np.random.default_rng(3)
    n, dt = 1500, 0.02
    smooth = signal.lfilter([0.02], [1, -0.98], rng.standard_normal((n, 2)), axis=0)
    d = smooth / np.linalg.norm(smooth) * 3.0  # a fixed, smooth prediction change

    def z(noise, e):
        we, wd = noise.whiten(e), noise.whiten(d)
        return float(np.sum(we * wd) / np.linalg.norm(wd))

    ours = []
    for _ in range(30):
        e = signal.lfilter([1.0], [1, -0.95], rng.standard_normal((n, 2)), axis=0)  # coloured null
        fitting = SimpleNamespace(residuals=lambda p, data, e=e: [e - d], dt=dt, segment=np.inf)
        ours.append(z(_held_out_noise(fitting, None, "validation", 0.5), e))
    assert 0.6 < np.std(ours) < 1.5, np.std(ours)
