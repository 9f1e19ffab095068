"""What a frame gives and the files it goes to: the `Frame` and its `FrameStats` (`frame`),
metric depth, normals, point clouds and their files (`outputs`, written atomically:
`atomic`), shading and depth pictures (`shade`, `textures`), and the demo's lettering
(`annotate`)."""
