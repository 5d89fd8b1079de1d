"""``python -m hbake.cli``: the ``hbake`` command (batch runs its bakes this way)."""
from hbake.cli.main import main

main()
