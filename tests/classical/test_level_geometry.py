"""A level's maps from the optics: computed once per rig and range, a hit bitwise what computing again gives."""

import pytest
import torch

import prismstereo.classical.level_geometry as lg
from prismstereo import PrismStereo, thesis_setup1
from prismstereo.epipolar.sweep import fit_sweep
from prismstereo.errors import OptionError
from prismstereo.geometry.optics import trace_pixels

Z = (450.0, 900.0)


def test_maps_are_the_traced_masks_and_a_hit_is_an_equal_copy(monkeypatch):
    monkeypatch.setattr(lg, "_CACHE", type(lg._CACHE)())
    rig = thesis_setup1().downscaled(8)
    fit = fit_sweep(rig, Z)
    first = lg.level_geometry(rig, Z, fit, rig.reference_width)
    h, w_ref = rig.image_height, rig.reference_width
    assert first.reference_valid.shape == (h, w_ref) and first.interval.shape == (2, h, w_ref)
    u, v = torch.meshgrid(torch.arange(w_ref, dtype=torch.float64), torch.arange(h, dtype=torch.float64),
                          indexing="xy")
    rays = trace_pixels(rig, torch.stack([u, v], -1).view(-1, 2))
    assert torch.equal(first.reference_valid, (rays.valid & rays.left).view(h, w_ref))
    calls = []
    compute = lg._compute
    monkeypatch.setattr(lg, "_compute", lambda *a: calls.append(a) or compute(*a))
    first.interval.fill_(0.0)  # a copy: the cache keeps its own
    again = lg.level_geometry(rig, Z, fit, rig.reference_width)
    assert not calls  # a hit
    fresh = compute(rig, fit, rig.reference_width, lg.fine_coefficients(rig, fit))
    for name, a, b in zip(fresh._fields, again, fresh, strict=True):
        assert torch.equal(a, b), name
    lg.level_geometry(rig, (450.0, 901.0), fit_sweep(rig, (450.0, 901.0)), rig.reference_width)
    assert len(calls) == 1  # another range: computed


def test_least_recently_used_ones_go(monkeypatch):
    monkeypatch.setattr(lg, "_CACHE", type(lg._CACHE)())
    monkeypatch.setattr(lg, "KEPT", 2)
    rig = thesis_setup1().downscaled(16)
    ranges = [(450.0, 900.0 + k) for k in range(3)]
    for z in ranges:
        lg.level_geometry(rig, z, fit_sweep(rig, z), rig.reference_width)
    kept = [key[1] for key in lg._CACHE]
    assert kept == [tuple(float(x).hex() for x in z) for z in ranges[1:]]
    one = sum(t.numel() * t.element_size() for t in next(iter(lg._CACHE.values())))
    monkeypatch.setattr(lg, "KEPT_BYTES", one + 1)  # room for one: the newest stays
    z = (450.0, 950.0)
    lg.level_geometry(rig, z, fit_sweep(rig, z), rig.reference_width)
    assert [key[1] for key in lg._CACHE] == [tuple(float(x).hex() for x in z)]


def test_models_built_twice_are_the_same(monkeypatch):
    rig = thesis_setup1().downscaled(8)
    a, b = PrismStereo(rig, Z), PrismStereo(rig, Z)
    for (name, x), y in zip(a.state_dict().items(), b.state_dict().values(), strict=True):
        assert torch.equal(x, y), name
    with pytest.raises(OptionError, match="rig must be a BiPrismRig"):
        lg.level_geometry("rig", Z, fit_sweep(rig, Z), 32)
