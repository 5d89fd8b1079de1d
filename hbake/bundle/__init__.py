"""The haptic bundle (``.hbundle``), the reference implementation of docs/bundle-format.md."""
from hbake.bundle import validate as _impl

# Transitional: the module's names, until it is split by concern.
globals().update({k: v for k, v in vars(_impl).items() if not k.startswith("__")})
