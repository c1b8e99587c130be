"""SweepSampler / sweep_sampler: shapes, the grid against exact projections (full resolution) and against the
binned rig's own sweep (blocks), precomputed validity equal to the per-call rule, errors, float64 gradcheck, and
the one sampler behind the classical sweep search and PrismCostVolume."""

import pytest
import torch

from prismstereo import thesis_setup1
from prismstereo.epipolar.grids import normalise_right_grid
from prismstereo.epipolar.row_rectify import level_coverage
from prismstereo.epipolar.sweep import fit_sweep, sweep_positions, sweep_to_depth
from prismstereo.errors import OptionError, PrismStereoError, ShapeError
from prismstereo.geometry import points_at_depth, project_points, trace_pixels
from prismstereo.matching.sweep_sampler import SweepSampler, block_centres, sweep_sampler

pytestmark = pytest.mark.usefixtures("one_thread")

Z_RANGE = (400.0, 900.0)


@pytest.fixture(scope="module")
def rig():
    return thesis_setup1().downscaled(8)  # 128 x 96, w_ref 64


@pytest.fixture(scope="module")
def fit(rig):
    return fit_sweep(rig, Z_RANGE)


def _other_valid(rig):
    w_ref = rig.reference_width
    uv = torch.stack(torch.meshgrid(torch.arange(w_ref, rig.image_width, dtype=torch.float64),
                                    torch.arange(rig.image_height, dtype=torch.float64), indexing="xy"), -1)
    rays = trace_pixels(rig, uv)
    return rays.valid & ~rays.left


def test_full_resolution_grid_is_the_exact_projection(rig, fit):
    sampler = sweep_sampler(fit, 5, other_start=rig.reference_width, other_valid=_other_valid(rig), precompute=False)
    grid = sampler.grid()
    assert grid.shape == (5, 96, 64, 2) and grid.dtype == torch.float64 and sampler.valid is None
    uv = block_centres(96, 64, 1, grid)
    rays = trace_pixels(rig, uv)
    depths = sweep_to_depth(torch.linspace(-1, 1, 5, dtype=torch.float64), fit.z_range)
    for i, z in enumerate(depths):
        proj = project_points(rig, points_at_depth(rays, z), "right")
        ok = proj.valid & rays.valid & rays.left
        assert int(ok.sum()) > 3000
        expected = normalise_right_grid(proj.uv, rig)
        assert float((grid[i] - expected).abs()[ok].max()) < 1e-3 * 2 / 64  # 1e-3 px in grid units


def test_blocks_are_the_binned_rig(rig, fit):
    """A level of 2 x 2 blocks samples where the binned rig's own sweep puts its pixels (to the fits' 1e-3 px)."""
    binned = rig.binned(2)
    other = level_coverage(_other_valid(rig), 2) > 0.999
    sampler = sweep_sampler(fit, 6, factor=2, other_start=rig.reference_width, other_valid=other)
    h, w = sampler.coefficients.shape[1:3]
    assert (h, w) == (48, 32) and other.shape == (48, 32)
    uv = block_centres(h, w, 1, fit.coefficients)
    expected = normalise_right_grid(sweep_positions(fit_sweep(binned, Z_RANGE), uv,
                                                    torch.linspace(-1, 1, 6, dtype=torch.float64).view(-1, 1, 1)),
                                    binned)
    assert float((sampler.grid() - expected).abs().max()) < 2e-3 * 2 / 32


def test_precomputed_validity_is_the_per_call_rule(rig, fit):
    other = _other_valid(rig)
    fixed = sweep_sampler(fit, 7, other_start=rig.reference_width, other_valid=other)
    checked = sweep_sampler(fit, 7, other_start=rig.reference_width, other_valid=other, precompute=False)
    image = torch.rand(2, 1, 96, 64, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    a, b = fixed(image), checked(image)
    assert a.image.shape == (2, 1, 7, 96, 64) and a.valid.shape == (2, 7, 96, 64)
    assert torch.equal(a.valid, b.valid) and torch.equal(a.image, b.image)
    assert 0.3 < float(a.valid.double().mean()) < 1.0  # some hypotheses leave the other half
    # dtype follows the image; a given grid replaces the sampler's own
    assert fixed(image.float()).image.dtype == torch.float32
    torch.testing.assert_close(fixed(image, fixed.grid() * 0.0).image[:, :, 0], fixed(image, fixed.grid() * 0.0)
                               .image[:, :, -1])


def test_gradcheck_image(rig, fit):
    sampler = sweep_sampler(fit, 3, factor=8, other_start=rig.reference_width,
                            other_valid=torch.ones(12, 8, dtype=torch.bool))
    image = torch.rand(1, 1, 12, 8, dtype=torch.float64, generator=torch.Generator().manual_seed(1),
                       requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: sampler(x).image, (image,), eps=1e-6, atol=1e-6)


def test_one_sampler_for_the_classical_search_and_the_volume():
    from prismstereo.classical.model import PrismStereo
    from prismstereo.nn import PrismCostVolume

    rig = thesis_setup1().downscaled(8)
    model = PrismStereo(rig, Z_RANGE, {"sampling": "sweep", "coarse_factor": 2})
    single = PrismStereo(rig, Z_RANGE, "reference")
    volume = PrismCostVolume(rig, Z_RANGE, model.final.search.num_hypotheses, 2)
    for sampler in (model.final.search.sampler, single.final.search.sampler, volume.sampler):
        assert type(sampler) is SweepSampler
    # the coarse level and the volume at the same binning: the same positions, the volume's mask within the level's
    torch.testing.assert_close(volume.grid, model.final.search.sampler.grid())
    assert not (volume.valid & ~model.final.search.sampler.valid).any()


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        (lambda: SweepSampler(torch.zeros(3, 4, 5, 2), 4), OptionError, "either its samples' validity"),
        (lambda: SweepSampler(torch.zeros(3, 4, 5, 2), 4, valid=torch.ones(4, 4, 5, dtype=torch.bool),
                              other_valid=torch.ones(4, 5, dtype=torch.bool)), OptionError, "either"),
        (lambda: SweepSampler(torch.zeros(3, 4, 5, 2), 1, other_valid=torch.ones(4, 5, dtype=torch.bool)),
         OptionError, "num_hypotheses must be an int >= 2"),
        (lambda: SweepSampler(torch.zeros(3, 4, 5), 4, other_valid=torch.ones(4, 5, dtype=torch.bool)),
         ShapeError, r"coefficients must be \(N, h, w, 2\)"),
        (lambda: SweepSampler(torch.zeros(3, 4, 5, 2), 4, valid=torch.ones(3, 4, 5, dtype=torch.bool)),
         ShapeError, r"valid must be \(4, 4, 5\)"),
    ],
)
def test_bad_samplers(call, error, match):
    with pytest.raises(error, match=match) as info:
        call()
    assert isinstance(info.value, PrismStereoError)


def test_bad_builder_options(rig, fit):
    other = torch.ones(96, 64, dtype=torch.bool)
    with pytest.raises(OptionError, match="factor must be an int >= 1"):
        sweep_sampler(fit, 4, factor=0, other_start=64, other_valid=other)
    with pytest.raises(ShapeError, match=r"coefficients must be \(N, 96, 64, 2\)"):
        sweep_sampler(fit, 4, other_start=64, other_valid=other, coefficients=torch.zeros(3, 10, 10, 2))
