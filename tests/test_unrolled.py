"""The unrolled correction (vrcorrect.learn.unrolled, issue 25): its untrained twin is fast's ADMM,
iteration for iteration; the box holds at every stage whatever the prior says; errors name the field."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vrcorrect.learn.unrolled import FAST_RELAXATION, FAST_RHO, UnrolledADMM, UnrolledConfig, kernel_spectra, twin
from vrcorrect.physics.kernel import build_kernel, build_reference_kernel
from vrcorrect.plumbing.charts import siemens_star
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.solvers import make_problem
from vrcorrect.solvers.admm import _admm, fast_start
from vrcorrect.specs.display import decode, get_display
from vrcorrect.specs.prescription import EyeRx

SIZE = (40, 52)


@pytest.fixture(scope="module")
def case():
    display = get_display("quest2")
    eye = EyeRx(sphere_D=-2.0, cylinder_D=-1.0, axis_deg=30.0, pupil_diameter_mm=4.0)
    kernel = build_kernel(eye, display)
    star = siemens_star(max(SIZE))[:SIZE[0], :SIZE[1]]
    problem = make_problem(decode(display, star).astype(np.float32), kernel, build_reference_kernel(eye, display))
    t_lms = np.ascontiguousarray(problem.target_lms.transpose(2, 0, 1), np.float32)
    z0 = np.ascontiguousarray(problem.target.transpose(2, 0, 1), np.float32)
    spectrum, gram, norm2 = kernel_spectra([kernel.kernel], SIZE, power_of_two=False)   # fast's grid
    return kernel, t_lms, z0, (spectrum, gram), norm2


def _run(model, case, **kw):
    _, t_lms, z0, spectrum, norm2 = case
    with torch.no_grad():
        return model(torch.from_numpy(t_lms)[None], torch.from_numpy(z0)[None], *spectrum, norm2, **kw)[0].numpy()


@pytest.mark.parametrize("stages", [1, 3])
def test_the_twin_is_fasts_admm_iteration_for_iteration(case, stages):
    kernel, t_lms, z0, _, _ = case
    expected = _admm(kernel.kernel, t_lms, z0, FAST_RHO, FAST_RELAXATION, 1.0, stages, 0.0, track=False)[0]
    got = _run(twin(stages), case)
    assert got.shape == (3, *SIZE)
    assert np.abs(got - expected[:, :SIZE[0], :SIZE[1]]).max() < 1e-5


@pytest.mark.parametrize("box_weight", [10.0, 0.3, 0.01, 1e-3])   # the range's ends and between
def test_a_box_weight_of_its_own_is_admm_with_that_weight(case, box_weight):
    """The stage's inverse from the eigen-decomposition at another box weight equals the numpy
    ADMM's cofactor inverse at that weight (its ``balance`` scales the retina penalty too, hence
    rho / weight), and differs from the twin at fast's weight."""
    kernel, t_lms, z0, _, _ = case
    expected = _admm(kernel.kernel, t_lms, z0, FAST_RHO / box_weight, FAST_RELAXATION, box_weight, 3, 0.0,
                     track=False)[0][:, :SIZE[0], :SIZE[1]]
    got = _run(twin(3, box_weight=box_weight), case)
    assert np.abs(got - expected).max() < 1e-4
    assert np.abs(got - _run(twin(3), case)).max() > 1e-2


def test_the_twins_stages_lower_the_objective_stage_by_stage(case):
    """From the target with zero duals the first stage moves only the retina split (z stays), then
    each stage lowers the objective."""
    kernel, t_lms, z0, spectrum, norm2 = case
    history: list[torch.Tensor] = []
    _run(twin(4), case, history=history)
    from vrcorrect.learn.train import objective_per_sample

    k = torch.from_numpy(kernel.kernel).float()[None]
    start = objective_per_sample(torch.from_numpy(z0)[None], k, torch.from_numpy(t_lms)[None]).item()
    values = [objective_per_sample(z, k, torch.from_numpy(t_lms)[None]).item() for z in history]
    assert len(values) == 4 and values[0] == pytest.approx(start, rel=1e-5)
    assert all(b < a for a, b in zip(values, values[1:])) and values[-1] < 0.95 * start


def test_an_untrained_model_returns_its_twin_exactly(case):
    model = UnrolledADMM(UnrolledConfig(stages=3, prior_width=8, features=4))
    features = torch.tensor([[0.3, -0.2, 0.1, 0.5]])
    assert np.array_equal(_run(model, case, features=features), _run(twin(3), case))


def test_the_box_holds_at_every_stage_whatever_the_prior_says(case):
    model = UnrolledADMM(UnrolledConfig(stages=3, prior_width=8, features=0))
    with torch.no_grad():
        model.prior.out.bias.fill_(5.0)                  # a prior pushing far above white
    history: list[torch.Tensor] = []
    out = _run(model, case, history=history)
    assert out.max() <= 1.0 and out.min() >= 0.0
    assert all(float(z.max()) <= 1.0 and float(z.min()) >= 0.0 for z in history)
    assert out.mean() > 0.9                             # it did push: the box, not the prior, held it


def test_training_reaches_the_stage_settings_and_the_prior(case):
    kernel, t_lms, z0, spectrum, norm2 = case
    from vrcorrect.learn.train import objective_per_sample

    model = UnrolledADMM(UnrolledConfig(stages=2, prior_width=4, features=4))
    z = model(torch.from_numpy(t_lms)[None], torch.from_numpy(z0)[None], *spectrum, norm2,
              features=torch.ones(1, 4))
    loss = objective_per_sample(z, torch.from_numpy(kernel.kernel).float()[None], torch.from_numpy(t_lms)[None]).sum()
    loss.backward()
    for name, p in (("stage_base", model.stage_base), ("mlp", model.mlp[-1].weight), ("prior", model.prior.out.weight)):
        assert p.grad is not None and torch.isfinite(p.grad).all() and p.grad.abs().max() > 0, name


@pytest.mark.parametrize("field, value", [("stages", 0), ("stages", 33), ("prior_width", -1), ("features", 2.5),
                                          ("box_weight", 0.0), ("box_weight", 1e-4), ("box_weight", 11.0),
                                          ("box_weight", float("nan")), ("box_weight", True),
                                          ("box_floor", 5e-4), ("box_floor", 1.5), ("box_floor", float("nan"))])
def test_bad_configurations_name_the_field(field, value):
    with pytest.raises(ValidationError, match=field):
        UnrolledConfig(**{field: value})


def test_a_box_weight_below_the_floor_is_refused():
    with pytest.raises(ValidationError, match="box_weight.*box_floor"):
        UnrolledConfig(box_weight=0.01, box_floor=0.05)


@pytest.mark.parametrize("floor", [1e-3, 0.05, 1.0])            # the floor's range: its ends and the default's
def test_no_stage_learns_a_box_weight_below_the_floor(floor):
    """Whatever the shared settings and the eye's correction ask, each stage's box weight is held
    at or above the floor, and left alone above it."""
    model = UnrolledADMM(UnrolledConfig(stages=3, prior_width=0, features=2, box_floor=floor))
    with torch.no_grad():
        model.stage_base[:, 2] = torch.tensor([np.log(1e-6), np.log(floor), np.log(2.0)])
        model.mlp[-1].bias.zero_()
    _, _, beta = model.stage_settings(torch.zeros(1, 2), 1)
    assert beta[0, 0].item() == pytest.approx(floor, rel=1e-6)          # asked for 1e-6: the floor
    assert beta[0, 1].item() == pytest.approx(floor, rel=1e-6)
    assert beta[0, 2].item() == pytest.approx(max(2.0, floor), rel=1e-6)  # above it: as asked
    with torch.no_grad():
        model.mlp[-1].bias.fill_(-50.0)                                 # the eye's correction pushes every setting down
    _, _, beta = model.stage_settings(torch.zeros(1, 2), 1)
    assert torch.allclose(beta, torch.full_like(beta, floor), rtol=1e-6)


def test_a_spectrum_smaller_than_the_image_is_refused(case):
    _, t_lms, z0, _, _ = case
    small, gram, norm2 = kernel_spectra([np.ones((3, 3, 3, 3)) / 27], (8, 8))
    T = (torch.from_numpy(t_lms)[None], torch.from_numpy(z0)[None])
    with pytest.raises(ValidationError, match="spectrum"):
        twin(1)(*T, small, gram, norm2)
    with pytest.raises(ValidationError, match="spectrum"):
        twin(1)(*T, small[..., 0], gram[..., 0], norm2)
    with pytest.raises(ValidationError, match="spectrum"):
        twin(1)(*T, small, gram[:, :, :, :4], norm2)


def test_from_fasts_start_the_twin_continues_fasts_admm_with_its_duals():
    """At 64 px fast's start solves a half-resolution level and hands on its duals: the twin given
    both (z0, d1, d2) is fast's full-resolution iterations from there, and its stages end nearer
    fast's objective than the same stages from the target."""
    from vrcorrect.learn.train import objective_per_sample

    display = get_display("desktop")
    eye = EyeRx(sphere_D=-3.0, cylinder_D=-1.0, axis_deg=100.0, pupil_diameter_mm=5.0)
    kernel = build_kernel(eye, display)
    star = siemens_star(64)
    problem = make_problem(decode(display, star).astype(np.float32), kernel, build_reference_kernel(eye, display))
    t_lms = np.ascontiguousarray(problem.target_lms.transpose(2, 0, 1), np.float32)
    target = np.ascontiguousarray(problem.target.transpose(2, 0, 1), np.float32)
    z0, d1, d2 = fast_start(kernel.kernel, target, t_lms)
    assert np.abs(d1).max() > 0 and np.abs(z0 - target).max() > 0.05          # the coarse level ran
    expected = _admm(kernel.kernel, t_lms, z0, FAST_RHO, FAST_RELAXATION, 1.0, 3, 0.0, duals=(d1, d2), track=False)[0]
    spectra = kernel_spectra([kernel.kernel], (64, 64), power_of_two=False)
    def T(a):
        return torch.from_numpy(a)[None]

    with torch.no_grad():
        warm = twin(3)(T(t_lms), T(z0), *spectra, d1=T(d1), d2=T(d2))
        cold = twin(3)(T(t_lms), T(target), *spectra)
    assert np.abs(warm[0].numpy() - expected[:, :64, :64]).max() < 1e-5
    k = torch.from_numpy(kernel.kernel).float()[None]
    assert objective_per_sample(warm, k, T(t_lms)).item() < 0.95 * objective_per_sample(cold, k, T(t_lms)).item()


def test_under_the_light_cap_the_twin_is_fasts_capped_admm_from_fasts_capped_start():
    """The box's top ``upper`` (a robust design's light cap) holds at every stage, as in ``fast``:
    from ``fast_start(capped=True)`` the twin is the capped numpy ADMM iteration for iteration, keeps
    under the cap where the unit box goes past it, and differs from the uncapped twin."""
    from vrcorrect.solvers.problem import light_cap

    display = get_display("desktop")
    eye = EyeRx(sphere_D=-3.0, cylinder_D=-1.0, axis_deg=100.0, pupil_diameter_mm=5.0)
    kernel = build_kernel(eye, display)
    codes = np.full((64, 64, 3), 0.12)                           # light bars on a dark ground
    codes[:, 8:56:12] = 0.92
    problem = make_problem(decode(display, codes).astype(np.float32), kernel, build_reference_kernel(eye, display))
    t_lms = np.ascontiguousarray(problem.target_lms.transpose(2, 0, 1), np.float32)
    target = np.ascontiguousarray(problem.target.transpose(2, 0, 1), np.float32)
    cap = light_cap(target)
    z0, d1, d2 = fast_start(kernel.kernel, target, t_lms, capped=True)
    assert np.all(z0 <= cap + 1e-7) and np.abs(d1).max() > 0                   # the coarse level ran, capped
    expected = _admm(kernel.kernel, t_lms, z0, FAST_RHO, FAST_RELAXATION, 1.0, 3, 0.0, duals=(d1, d2), track=False,
                     upper=cap)[0][:, :64, :64]
    spectra = kernel_spectra([kernel.kernel], (64, 64), power_of_two=False)

    def T(a):
        return torch.from_numpy(a)[None]

    history: list[torch.Tensor] = []
    with torch.no_grad():
        capped = twin(3)(T(t_lms), T(z0), *spectra, d1=T(d1), d2=T(d2), upper=T(cap), history=history)[0].numpy()
        free = twin(3)(T(t_lms), T(z0), *spectra, d1=T(d1), d2=T(d2))[0].numpy()
    assert np.abs(capped - expected).max() < 1e-5
    assert all(float((z[0].numpy() - cap).max()) <= 1e-7 for z in history)
    assert (free - cap).max() > 0.05                   # the unit box lifts the dark ground past the cap
