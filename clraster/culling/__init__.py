"""Object culling on the host, before anything reaches the pipeline: clusters of at most 128
triangles with their bounds and normal cones (`clusters`), their BVHs (`bvh`), the view
frustum's planes (`frustum`), the per-view culling that makes a frame's draw list (`cull`),
and the fate of every cluster (`fates`)."""
