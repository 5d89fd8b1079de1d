"""Tools of the lab around the baker: procedural test models (procedural), texture
synthesis on a mesh (texture) and the bake benchmark (bench)."""
