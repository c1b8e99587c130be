"""The weights files' helpers: a module's part of a file's tensors."""

import torch

from prismstereo.learned.exact_confidence import ConfidenceHead
from prismstereo.learned.weights import state_part


def test_state_part_takes_one_modules_entries_without_the_prefix():
    torch.manual_seed(0)
    head = ConfidenceHead(channels=4)
    state = {**{f"head.{k}": v for k, v in head.state_dict().items()},
             "headless.bias": torch.ones(1), "half.0.head.bias": torch.zeros(2)}  # not under "head."
    part = state_part(state, "head")
    assert part.keys() == head.state_dict().keys()
    again = ConfidenceHead(channels=4)
    again.load_state_dict(part)  # what the module's load_state_dict takes
    assert all(torch.equal(a, b) for a, b in zip(again.state_dict().values(), head.state_dict().values(), strict=True))
    assert state_part(state, "quarter") == {}
