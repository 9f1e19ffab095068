"""Host side of each OpenCL stage: its device buffers (one dataclass per stage boundary) and
the launches. Each stage's ``run`` takes the upstream stage's buffers and the frame's
`clraster.pipeline.params.FrameParams` and returns its own buffers; `chain.StageChain` runs them in
order (the renderer, the occlusion query and any partial pass of a frame use it). Stages
never import the renderer."""
