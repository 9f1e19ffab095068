"""The per-pass memory figures that the docstrings quote (`Renderer`, `RasterConfig`) are the
ones `StageChain.budget_bounds` computes."""

from __future__ import annotations

import clraster
from clraster import RasterConfig
from clraster.pipeline.renderer import Renderer


def _pass_bytes(config: RasterConfig) -> int:
    return sum(Renderer(16, 16, config=config).chain.budget_bounds().values())


def test_docstrings_quote_the_budget_bounds():
    m, e = 1 << 12, 1 << 12
    base = _pass_bytes(RasterConfig(batch_triangles=m, batch_entries=e))
    per_m = (_pass_bytes(RasterConfig(batch_triangles=2 * m, batch_entries=e)) - base) // m
    per_e = (_pass_bytes(RasterConfig(batch_triangles=m, batch_entries=2 * e)) - base) // e
    assert base == per_m * m + per_e * e
    d = RasterConfig()
    mib = (per_m * d.batch_triangles + per_e * d.batch_entries) / 2**20
    doc = " ".join((Renderer.__doc__ or "").split())
    assert f"≤ {per_m}·M + {per_e}·E bytes ({mib:.0f} MiB at the defaults" in doc
    cdoc = " ".join((clraster.RasterConfig.__doc__ or "").split())
    assert f"at most {per_m} bytes per triangle of the budget" in cdoc
    assert f"Default ``1 << 20`` ({per_m * d.batch_triangles / 2**20:.0f} MiB" in cdoc
    assert d.batch_triangles == 1 << 20
