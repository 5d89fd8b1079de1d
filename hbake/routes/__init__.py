"""The bake routes: from a loaded mesh to a written bundle.

pipeline (``hbake.bake``: the cage route, the choice of route, the manifest and the
write), preserve (the paper's parameterization-preserving route, Sec. 6.1).
"""
