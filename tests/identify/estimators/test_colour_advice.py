"""ML's note on strongly coloured residuals ranks its causes: residuals that follow the inputs (an
undeclared delay) send the user to refine first; turbulence in open loop to the filter-error method."""
import numpy as np

from identify import ML, LinearModel, load_profile, simulate_run
from tests.identify.estimators.test_filter_error import DT, F_TRUE, NOISE, _elevator, _runs


def test_an_undeclared_delay_is_sent_to_refine_turbulence_to_fem():
    nav = load_profile("navion_cruise_long")
    truth = LinearModel(nav)
    t = np.arange(0, 20, DT)
    delayed = ML(nav).fit([simulate_run(truth, t, _elevator(t), noise=NOISE, seed=1, input_delay=0.15)]).result_
    note = delayed.info["estimator_advice"]
    assert note and "follow the inputs" in note and "`identify refine`" in note, note
    assert note.index("identify refine") < note.index("--method fem")  # refine first, FEM if it finds nothing
    gusty = ML(nav).fit(_runs(truth, F_TRUE, (2,), duration=20.0)).result_
    note = gusty.info["estimator_advice"]
    assert note and "do not follow the inputs" in note and "refine" not in note and "--method fem" in note, note
