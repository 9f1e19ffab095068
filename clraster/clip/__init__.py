"""2-D polygons in window pixels: polygon clipping (`clip2d`) and the polygon windows a frame is
drawn through (`window`: a window's pixel mask and the clip-space planes that bound it)."""
