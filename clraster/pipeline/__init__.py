"""The rasterization pipeline. One frame is `driver.render_frame` (the table of contents): the
frame plan (`drawlist`: culling and the draw records, `draws`), its parameters and totals
(`params`), the passes streamed within a memory budget (`streaming`) or the two phases of
occlusion culling (`twophase`, boxes: `boxes`), run by one of two backends: the OpenCL
renderer (`renderer`, its device and program cache `device`, host arrays `arraypool`, the
host side of each kernel `stages`) or the NumPy twin that mirrors the stages one by one
(`reference`). Beside it, on the same stages: exact occlusion queries (`occlusion`) and line
segments (`lines`, `segments`)."""
