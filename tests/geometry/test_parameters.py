import math

import pytest
import torch

from prismstereo import thesis_setup1
from prismstereo.geometry import RigParameters


def test_parameters(dtype):
    p = thesis_setup1().replace(prism_offset_x_mm=2.0, prism_tilt_deg=(1.0, 0.0, 0.0)).parameters(dtype=dtype)
    assert isinstance(p, RigParameters)
    assert p.alpha.dtype == dtype and p.alpha.shape == ()
    assert p.alpha.item() == pytest.approx(math.radians(6.4))
    assert p.tilt.shape == (3,) and p.tilt[0].item() == pytest.approx(math.radians(1.0))
    assert p.d.item() == 2.0 and (p.width, p.height) == (1024, 768)
    q = p.to(torch.zeros(1, dtype=torch.float64))
    assert q.n.dtype == torch.float64 and q.width == 1024


def test_parameters_requires_grad():
    p = thesis_setup1().parameters(dtype=torch.float64, requires_grad=True)
    assert all(t.requires_grad for t in p if isinstance(t, torch.Tensor))
    # .to keeps the autograd graph
    q = p.to(torch.zeros(1, dtype=torch.float32))
    q.alpha.backward()
    assert p.alpha.grad is not None and p.alpha.grad.item() == 1.0
