import torch

from prismstereo.geometry import refract

F64 = torch.float64


# ----------------------------------------------------------------------------- refract
def test_refract_snell_law():
    gen = torch.Generator().manual_seed(1)
    inc = torch.randn(500, 3, generator=gen, dtype=F64)
    inc[:, 2] = inc[:, 2].abs() + 0.5
    inc = inc / inc.norm(dim=-1, keepdim=True)
    normal = torch.tensor([0.1, -0.2, -1.0], dtype=F64)
    normal = normal / normal.norm()
    for eta in (1 / 1.5, 1.5):
        out = refract(inc, normal, eta)
        sin_i = torch.linalg.cross(inc, normal.expand_as(inc)).norm(dim=-1)
        sin_t = torch.linalg.cross(out.directions, normal.expand_as(inc)).norm(dim=-1)
        v = out.valid
        torch.testing.assert_close(sin_t[v], eta * sin_i[v])
        torch.testing.assert_close(out.directions.norm(dim=-1)[v], torch.ones_like(sin_i[v]))
        # coplanar with incident ray and normal
        triple = (torch.linalg.cross(inc, normal.expand_as(inc)) * out.directions).sum(-1)
        assert triple[v].abs().max() < 1e-12
        # keeps going forward through the surface
        assert ((out.directions @ normal)[v] < 0).all()
        assert torch.equal(v, eta * sin_i < 1)
    assert not refract(inc, normal, 1.5).valid.all()  # some are totally internally reflected


def test_refract_tir_gradients_are_finite():
    inc = torch.tensor([[0.8, 0.0, 0.6], [0.1, 0.0, 0.995]], dtype=F64, requires_grad=True)
    out = refract(inc / inc.norm(dim=-1, keepdim=True), torch.tensor([0.0, 0.0, -1.0], dtype=F64), 1.5)
    assert out.valid.tolist() == [False, True]
    out.directions.sum().backward()
    assert torch.isfinite(inc.grad).all()


def test_large_batches_refract_bit_for_bit_as_small_ones():
    """Large eager batches take a faster dot product than small ones: the same floats, signed zeros included."""
    d = torch.zeros(20_000, 3, dtype=F64)
    d[::2, :2], d[:, 2] = -0.0, 1.0  # the axis ray, with signed zeros
    m = torch.tensor([-0.0, 0.0, -1.0], dtype=F64)
    big, small = refract(d, m, 1 / 1.5).directions, refract(d[:10], m, 1 / 1.5).directions
    assert torch.equal(big[:10].view(torch.int64), small.view(torch.int64))
