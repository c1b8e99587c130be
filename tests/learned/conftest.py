"""Fixtures shared by the hybrid's tests (tests/learned/test_hybrid.py, test_exact_stage.py): its 512 x 384 rig and a
textured plane through it, rendered once per worker. Modules with a rig of their own define ``rig`` themselves."""

import pytest

from prismstereo import thesis_setup1
from prismstereo.synthetic import ImageFormation, fronto_parallel_plane, render


@pytest.fixture(scope="session")
def rig():
    return thesis_setup1().downscaled(2)


@pytest.fixture(scope="session")
def plane(rig):
    return render(rig, fronto_parallel_plane(rig, 600.0, seed=3), ImageFormation(supersample=2, noise_sigma=1 / 255))
