"""The stages of a bake, in the order the routes run them.

load (read, validate and repair the full-resolution mesh), simplify (the coarse mesh),
parameterize (the texture atlas's charts), atlas (the haptic texture, by rays),
decompose (convex pieces), mass (mass properties), quality (the manifest's error
measures); geometry holds the vectorised mesh geometry they share. Each stage is a
function of meshes and its settings (hbake.settings) and writes no file.
"""
