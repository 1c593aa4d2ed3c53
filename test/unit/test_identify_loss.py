"""The identification's loss: how a residual counts. Its cost and its reweighting must be the
ones scipy's least_squares minimises and steps by, or the standard errors and the left-out-day
steps would belong to another fit than the one made."""
import numpy as np
import pytest
from scipy.optimize import least_squares

from mantis_sim.studies.real_strikes.identify import IdentificationError, Loss


@pytest.mark.parametrize('text, loss', [('linear', Loss()), ('cauchy:0.05', Loss('cauchy', 0.05)),
                                        ('soft_l1:1', Loss('soft_l1', 1.0))])
def test_a_loss_is_read_from_name_and_scale(text, loss):
    assert Loss.parse(text) == loss


@pytest.mark.parametrize('text, message', [('l1', 'NAME must be one of'),
                                           ('huber', 'a robust loss needs SCALE'),
                                           ('huber:0', 'a robust loss needs SCALE'),
                                           ('huber:x', 'a robust loss needs SCALE'),
                                           ('cauchy:inf', 'a robust loss needs SCALE'),
                                           ('linear:0.3', 'takes no SCALE')])
def test_a_bad_loss_is_refused_naming_it(text, message):
    with pytest.raises(IdentificationError, match=message):
        Loss.parse(text)
    with pytest.raises(IdentificationError, match='must be one of'):
        Loss('bogus')


@pytest.mark.parametrize('name', Loss.NAMES)
def test_cost_and_weights_are_scipy_s(name):
    """Fit a line to data with an outlier: the cost at scipy's solution is scipy's, and the
    gradient of the cost is J^T (w^2 r) with our weights w (what the reweighted steps use)."""
    rng = np.random.default_rng(7)
    x = np.linspace(0.0, 1.0, 20)
    y = 2.0 * x + 0.5 + 0.01 * rng.standard_normal(x.size)
    y[3] += 1.0
    design = np.column_stack([x, np.ones_like(x)])
    loss = Loss(name, 0.05)

    def residual(p):
        return design @ p - y
    solution = least_squares(residual, [1.0, 0.0], loss=loss.name, f_scale=loss.scale)
    assert loss.cost(residual(solution.x)) == pytest.approx(solution.cost, rel=1e-9)
    p = np.array([1.7, 0.2])
    w = loss.row_weights(residual(p))
    gradient = design.T @ (w ** 2 * residual(p))
    h = 1e-6
    numeric = [(loss.cost(residual(p + h * e)) - loss.cost(residual(p - h * e))) / (2 * h)
               for e in np.eye(2)]
    assert gradient == pytest.approx(numeric, rel=1e-5)
    if name != 'linear':            # a robust loss is pulled far less by the outlier
        plain = least_squares(residual, [1.0, 0.0]).x
        pull = np.abs(solution.x - [2.0, 0.5])
        assert np.all(pull < 0.3 * np.abs(plain - [2.0, 0.5]))
        at_solution = loss.row_weights(residual(solution.x))
        assert at_solution[3] < 0.5 * np.median(at_solution)
