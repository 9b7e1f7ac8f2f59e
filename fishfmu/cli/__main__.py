"""``python -m fishfmu.cli``: the same as the ``fishfmu`` command."""

from fishfmu.cli import main

main()
