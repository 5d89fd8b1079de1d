"""The ``hbake`` command: thin click layers over the library.

main holds the group and ``hbake bake``; batch, bundle, lab and view hold the other
commands. No module outside this package imports click.
"""
from hbake.cli.main import main  # noqa: F401
