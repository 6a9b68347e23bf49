"""choose_accuracy: the configuration it picks for a tolerance meets it, against the closed forms."""
import pytest

import tensegrity_sim as ts
from bench.analytic import bungee_dict, bungee_exact, deadband_dict, deadband_exact

CASES = {"bungee": (bungee_dict, lambda t: bungee_exact(t)[0], (1, 2)),
         "deadband": (deadband_dict, lambda t: deadband_exact(t)[0], (1, 0))}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("tol, order", [(1e-7, 2), (1e-10, 4)])
def test_the_choice_meets_the_tolerance(case, tol, order):
    """Order 2 (located, a smaller step) for 1e-7 m over 2 s, order 4 for 1e-10 m; the estimate is the
    error to within a factor 2 and the error is within ``tol`` (measured: bungee 5.0e-8 m at 0.205 ms and
    2.9e-12 m at 1 ms; dead band 5.0e-8 m at 0.277 ms and 3.6e-13 m at 1 ms)."""
    make, exact, index = CASES[case]
    scene = ts.Scene.from_dict(make())
    choice = ts.choose_accuracy(scene, tol, 2.0)
    assert choice.order == order and choice.locate_switches, choice.reason
    sim = ts.Simulator(scene, **choice.options())
    sim.run(duration=2.0)
    error = abs(sim.positions[index] - exact(2.0))
    assert error <= tol
    assert 0.5 < choice.estimated_error / error < 2.0
    assert round(2.0 / choice.dt) * choice.dt == pytest.approx(2.0, rel=1e-12)


def test_bad_requests_are_refused():
    scene = ts.Scene.from_dict(bungee_dict())
    with pytest.raises(ValueError, match=r"tol must be a final-position error > 0 \(m\), got 0\.0"):
        ts.choose_accuracy(scene, 0.0, 1.0)
    with pytest.raises(ValueError, match=r"duration must be > 0 \(s\), got -1\.0"):
        ts.choose_accuracy(scene, 1e-6, -1.0)
    with pytest.raises(ValueError, match=r"tol must be a number, got 'small'"):
        ts.choose_accuracy(scene, "small", 1.0)
    with pytest.raises(ValueError, match=r"scene must be a Scene"):
        ts.choose_accuracy({"nodes": []}, 1e-6, 1.0)
