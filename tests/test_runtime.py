"""The operations whose fastest form differs between torch eager and onnxruntime (:mod:`prismstereo.runtime`): each
pair computes the same numbers, checked here by taking the exported form in eager (``exporting`` patched on); the
exported graphs themselves are checked against torch in tests/export and tests/matching."""

import pytest
import torch
import torch.nn.functional as F

import prismstereo.runtime as runtime

GEN = torch.Generator().manual_seed(4)


@pytest.fixture
def exported(monkeypatch):
    """Call ``f(*args)`` with the exported forms taken (as under ``torch.onnx.export``)."""
    def run(f, *args):
        with monkeypatch.context() as patch:
            patch.setattr(runtime, "exporting", lambda: True)
            return f(*args)
    return run


def test_box_filters_match_their_exported_pools(exported):
    volume = torch.rand(2, 3, 9, 7, generator=GEN)
    for window in (3, 5, 21):  # a window wider than the map: pixels inside the image only
        torch.testing.assert_close(runtime.box_mean(volume, window), exported(runtime.box_mean, volume, window))
        r = window // 2
        pooled = F.max_pool2d(F.max_pool2d(volume, (window, 1), 1, (r, 0)), (1, window), 1, (0, r))
        assert torch.equal(runtime.box_max(volume, window), pooled)
    assert torch.equal(runtime.box_mean(torch.ones(1, 1, 4, 4), 3), torch.ones(1, 1, 4, 4))


def test_fill_invalid_and_its_bounded_form(exported):
    volume = torch.rand(1, 4, 5, 6, generator=GEN)
    valid = torch.rand(1, 4, 5, 6, generator=GEN) > 0.3
    expected = torch.where(valid, volume, torch.full_like(volume, 1.0))
    for bounded in (False, True):
        assert torch.equal(runtime.fill_invalid(volume, valid, 1.0, bounded), expected)
        assert torch.equal(exported(runtime.fill_invalid, volume, valid, 1.0, bounded), expected)


def test_sgm_scans_and_bilinear_samples_agree_between_forms(exported):
    volume = -torch.rand(6, 2, 5, 7, generator=GEN)
    p2s = torch.rand(6, 2, 1, 7, generator=GEN) + 0.5
    for shift in (0, 1):
        assert torch.equal(runtime.scan_eager(volume, 0.1, 0.6, shift, p2s),
                           runtime.scan_traced(volume, 0.1, 0.6, shift, p2s))
    image = torch.rand(2, 1, 6, 8, generator=GEN)
    x, y = 9 * torch.rand(2, 3, 4, 5, generator=GEN) - 1, 7 * torch.rand(2, 3, 4, 5, generator=GEN) - 1
    torch.testing.assert_close(exported(runtime.sample_bilinear, image, x, y), runtime.sample_bilinear(image, x, y),
                               atol=1e-6, rtol=0)  # positions outside the image clamped in both


def test_scatter_min_crop_and_flat_index():
    data = torch.full((2, 6), 9.0)
    index = torch.tensor([[0, 0, 5], [1, 2, 2]])
    updates = torch.tensor([[3.0, 2.0, 4.0], [1.0, 7.0, 5.0]])
    assert torch.equal(runtime.scatter_min(data, index, updates), data.scatter_reduce(1, index, updates, "amin"))
    t = torch.zeros(1, 1, 5, 4)
    assert runtime.crop(t, 5, 4) is t and runtime.crop(t, 3, 2).shape == (1, 1, 3, 2)
    index = runtime.flat_index(torch.tensor([1.0, 99.0]), torch.tensor([2.0, 0.0]), 4, 12)
    assert index.dtype == torch.int32 and index.tolist() == [6, 11]  # clamped into the image
