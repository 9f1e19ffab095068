"""The ground floor, imported by every layer and importing nothing else of clraster: the
tunables (`config.RasterConfig`, turned into the kernels' ``-D`` options), the constants and
record layouts shared with the OpenCL C kernels (`layout`), and the checks of every input
(`checks`)."""
