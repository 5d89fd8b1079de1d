"""hrt: the haptic rendering runtime from Python (docs/python.md).

    import numpy as np, hrt
    a = hrt.load_bundle("probe.hbundle")
    b = hrt.load_bundle("plate.hbundle")
    scene = hrt.Scene([a, b])                      # options as `hrt query`'s
    r = scene.query(np.array([[0, 0, 0.0168, 0, 0, 0, 1],
                              [0, 0, 0, 0, 0, 0, 1.0]]))
    r["force"], r["torque"], r["patches"]["delta"]

Units and conventions are the bundle format's (docs/bundle-format.md): metres, N/m,
radians; a pose is x, y, z, qx, qy, qz, qw of a bundle's object frame in the world; a
patch's n points from the probe A into B and delta > 0 is overlap.
"""
from ._hrt import (BUNDLE_FORMAT_MAJOR, BUNDLE_FORMAT_MINOR, BundleError, DeviceError, GlError, Model, Runner,
                   Scene, SceneFileError, __version__, load_bundle)

__all__ = ["BUNDLE_FORMAT_MAJOR", "BUNDLE_FORMAT_MINOR", "BundleError", "DeviceError", "GlError", "Model", "Runner",
           "Scene", "SceneFileError", "__version__", "load_bundle"]
