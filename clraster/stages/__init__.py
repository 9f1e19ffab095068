"""Host side of each OpenCL stage: its device buffers (one dataclass per stage boundary) and
the launches. Stages never import the renderer; the renderer runs them in order."""
