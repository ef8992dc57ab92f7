"""refine with the frequency-response estimator: what CIFER's gates cannot determine is held first."""
import numpy as np

from identify import ML, LinearModel, load_profile, perturbed_model
from identify.estimators.frequency.response_fit import FR
from identify.refine.loop import Refine
from tests.identify.frequency.test_fr_cli import DT, sweep_run


def test_refine_fr_holds_what_the_gates_cannot_determine():
    p = load_profile("s61_hover_4dof")
    truth = perturbed_model(LinearModel(p), 0.3, np.random.default_rng(4))
    runs = [sweep_run(truth, np.arange(0, 20, DT), j, seed=j) for j in range(2)]
    # the estimator decides, through its hook: the base (ML) holds nothing
    assert ML(p).determinable(p, runs) == (p, {})
    r = Refine(p, estimator=FR(p, n_draws=0), max_steps=1, kinds=("scale",)).fit(runs)
    held = r.undeterminable_
    # 20 derivatives, most of them beyond what two 20-s sweeps show: held with CIFER's reason, not fitted
    assert 5 <= len(held) < len(p.free) and all("%" in why for why in held.values())
    assert set(r.initial_result_.names) == set(p.free) - set(held)
    # unpruned, the nested fit ran off (X_q -1487, Y_q -4581) without converging; pruned it converges near the truth
    assert r.initial_result_.converged and not any("declared model" in u for u in r.unconverged_)
    true = truth.parameters()
    for n, v in zip(r.initial_result_.names, r.initial_result_.theta):
        assert abs(v - true[n]) < 0.25 * abs(true[n]), (n, v, true[n])
    assert r.result_.info["undeterminable"] == held


def test_bootstrap_is_scaled_for_the_correction_ratio():
    """Where the bootstrap's premise holds (the structure predicts the runs to within their noise), its
    covariance is scaled by the linearised fit-and-correct fixed point's gain, one factor per parameter."""
    from identify.model.subset import fix

    p = load_profile("s61_hover_4dof")
    keep = ("L_p", "L_theta_c", "M_theta_s")  # what FR's gates keep on such runs (benchmarks/frequency_fit.py)
    p = fix(p, [n for n in p.free if n not in keep]).with_values({"L_p": -1.4, "L_theta_c": 16.0, "M_theta_s": 3.3})
    truth = LinearModel(load_profile("s61_hover_4dof"))
    runs = [sweep_run(truth, np.arange(0, 20, DT), j, seed=j) for j in range(2)]
    r = FR(p, n_draws=8).fit(runs).result_
    gain = r.info["ratio_gain"]
    assert len(gain) == 3 and all(0.8 < g < 1.5 for g in gain), gain  # benchmark mean: 1.13, 1.01, 1.00
    assert "linearised fixed point" in r.info["standard_errors"] and np.all(np.isfinite(r.std))
    true = truth.parameters()
    assert all(abs(v - true[n]) < 4 * s for n, v, s in zip(r.names, r.theta, r.std))  # the bounds cover the error
