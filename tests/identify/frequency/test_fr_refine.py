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
    # validation runs given: held out of the sweeps, refine would fit them without their last (fastest) third
    val = [sweep_run(truth, np.arange(0, 20, DT), j, seed=10 + j) for j in range(2)]
    r = Refine(p, estimator=FR(p, n_draws=0), max_steps=1, kinds=("scale",)).fit(runs, validate=val)
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


def test_refine_fr_finds_an_undeclared_derivative_by_its_own_likelihood_ratio():
    """Pitch case, truth with X_eta = 1 the declared model lacks. FR's gates hold X_u, yet the X equation
    stays in the catalogue (held, X_eta was never tried), and the nested ratio is FR's own (J's)."""
    from identify import parse_profile
    from tests.identify.refine.test_refine import PROFILE, TOML, make_runs

    fit, val = make_runs(parse_profile(TOML.replace("M_eta = 5.0", "M_eta = 5.0\nX_eta = 1.0")))
    r = Refine(PROFILE, estimator=FR(PROFILE, n_draws=12), kinds=("derivative",), max_steps=1).fit(fit, validate=val)
    assert "X_u" in r.undeterminable_
    assert [s.target for s in r.steps_] == ["X_eta"], [s.to_dict() for s in r.rejected_]
    step = r.steps_[0]
    assert step.lr_criterion == "frequency-response J" and step.lr_statistic > step.threshold
    est = step.parameters["X_eta"]
    assert abs(est["value"] - 1.0) < 3 * est["std"], est


def test_fr_nested_ratio_is_near_chi_square_for_a_spurious_entry():
    """On data without the effect FR's ratio for an added X_q is about chi-square(1) (mean 1); J's drop over
    its dispersion alone, the composite's correlated points taken as independent, is many times that."""
    from identify.refine.candidates import Derivative
    from tests.identify.refine.test_refine import PROFILE, make_runs

    own, independent = [], []
    for seed in range(5):
        fit, _ = make_runs(seeds=(100 + 3 * seed, 101 + 3 * seed, 102 + 3 * seed))
        null = FR(PROFILE, n_draws=12).fit(fit).result_
        alt = FR(Derivative("X_q").profile(PROFILE), n_draws=12).fit(fit).result_
        lr, df = alt.compare_lr_test(null)
        assert df == 1
        own.append(lr)
        independent.append((null.info["criterion"]["cost"] - alt.info["criterion"]["cost"])
                           / alt.info["criterion"]["dispersion"])
    assert np.mean(own) < 3.0, own  # chi-square(1) mean 1; five draws' mean stays below 3 in 98 % of cases
    assert np.mean(independent) > 4 * np.mean(own), (independent, own)


def test_compare_lr_test_only_where_the_estimator_states_its_criterion():
    """The statistic is the criterion's drop over its dispersion and the added parameter's inflation; ML's
    result states no criterion (refine keeps the time-domain metric: None); without a bootstrap FR's
    inflation is unknown (NaN, which refine refuses as undetermined, never a ratio of independent points)."""
    from identify.estimators.result import IdentificationResult
    from identify.model.subset import fix

    full = load_profile("s61_hover_4dof")
    small = fix(full, ["L_p"])

    def fr(profile, cost, inflation):
        crit = {"kind": "frequency-response J", "cost": cost, "dispersion": 0.01, "inflation": inflation}
        n = len(profile.free)
        return IdentificationResult("fr", profile, np.zeros(n), np.ones(n), info={"criterion": crit})

    assert fr(full, 10.0, {"L_p": 4.0}).compare_lr_test(fr(small, 12.0, {})) == (50.0, 1)
    lr, df = fr(full, 10.0, {"L_p": float("nan")}).compare_lr_test(fr(small, 12.0, {}))
    assert np.isnan(lr) and df == 1
    ml = IdentificationResult("ml", full, np.zeros(20), np.ones(20))
    assert ml.compare_lr_test(IdentificationResult("ml", small, np.zeros(19), np.ones(19))) is None
    from identify.refine.acceptance import failed_refit as _failed_refit

    assert "likelihood ratio is not determined" in _failed_refit(fr(full, 10.0, {}), lr, 1e4, 10.0, own=True)
