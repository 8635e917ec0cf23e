"""all_finite: the float64 sum's finiteness answers as an element-wise test does."""

from __future__ import annotations

import pytest
import torch

from mmcsplat.plugin_api.render_contract import all_finite

NAN, INF = float("nan"), float("inf")


@pytest.mark.parametrize("values", [[1.0, 2.0], [1.0, NAN], [INF, 1.0], [-INF, INF], [3e38] * 100, [-3e38, -3e38], [], [[1.0, NAN], [2.0, 3.0]]])
def test_all_finite_agrees_with_each_element(values):
    for dtype in (torch.float32, torch.float16, torch.float64):
        tensor = torch.tensor(values, dtype=dtype)
        assert all_finite(tensor) == bool(torch.isfinite(tensor).all())
    assert all_finite(torch.tensor(values, requires_grad=True)) == bool(torch.isfinite(torch.tensor(values)).all())
