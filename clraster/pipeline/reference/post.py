"""The NumPy twin of kernels/post.cl: SSAO's three passes and FXAA 3.11. They live in
`clraster.output.post` (render_shaded runs them on the host for renderers without a device);
this module names them where the twins of the other kernels are."""

from __future__ import annotations

from ...output.post import fxaa, luma, ssao, ssao_inputs, ssao_taps_pass, ssao_upsample

__all__ = ["fxaa", "luma", "ssao", "ssao_inputs", "ssao_taps_pass", "ssao_upsample"]
