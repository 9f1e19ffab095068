"""2-D polygons in window pixels: the polygon type and its validation (`polygon`, whose
O(n log n) candidate-pair search is `sweep`), polygon clipping (`clip2d`) and the polygon
windows a frame is drawn through (`window`: a window's pixel mask and the clip-space planes
that bound it). Imports go one way: window, clip2d → polygon → sweep."""
