"""The NumPy twin of kernels/shadow.cl: `clraster.output.lights.shadow_lookup` (render_shaded
runs it on the host for renderers without a device); named here beside the other twins."""

from __future__ import annotations

from ...output.lights import shadow_lookup

__all__ = ["shadow_lookup"]
