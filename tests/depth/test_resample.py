"""Maps of a binned grid brought to full resolution (:func:`prismstereo.depth.resample.upsample`) and the models'
result (:class:`~prismstereo.depth.result.DepthResult`)."""

import pytest
import torch

from prismstereo import OptionError
from prismstereo.depth import DepthResult, upsample


def test_upsample_covers_the_finer_level_and_its_errors():
    """Each level pixel covers f x f pixels; rows and columns the level does not reach repeat its last one or are
    0; a level reaching past the finer size is cut; options outside the choices are refused."""
    t = torch.arange(4.0).view(1, 1, 2, 2)
    near = upsample(t, 2, (5, 5))
    assert near.shape == (1, 1, 5, 5) and near[0, 0, 0].tolist() == [0.0, 0.0, 1.0, 1.0, 1.0]
    assert upsample(t, 2, (5, 5), beyond="zero")[0, 0, 4].tolist() == [0.0] * 5
    assert upsample(t, 2, (3, 3)).shape == (1, 1, 3, 3)
    linear = upsample(t, 2, (4, 4), "bilinear")  # between the centres of 0 and 1: 0.25 and 0.75
    assert linear[0, 0, 0].tolist() == [0.0, 0.25, 0.75, 1.0]
    with pytest.raises(OptionError, match="Unknown beyond 'wrap'"):
        upsample(t, 2, (4, 4), beyond="wrap")
    with pytest.raises(OptionError, match="Unknown mode 'bicubic'"):
        upsample(t, 2, (4, 4), "bicubic")


def test_depth_result_names_the_maps_of_every_model():
    """The one output of every model: five maps in a fixed order (the exported graphs keep the first three)."""
    assert DepthResult._fields == ("depth", "valid", "confidence", "index", "match")
    maps = DepthResult(*(torch.zeros(1, c, 2, 2) for c in (1, 1, 1, 1, 2)))
    assert maps.match.shape == (1, 2, 2, 2) and maps[:3] == (maps.depth, maps.valid, maps.confidence)
