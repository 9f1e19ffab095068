"""What is drawn and from where: meshes (`mesh`), scenes of instances (`scene`), what a caller
hands the renderers becoming a Mesh or Scene once (`inputs.as_target`), cameras and their
float32 limits (`camera`, `precision`), cameras from other tools' files and camera lists
(`camera_files`, `views`), the bundled example mesh (`examples`) and the procedural scenes
(`generators`). Imports only `clraster.base`."""
