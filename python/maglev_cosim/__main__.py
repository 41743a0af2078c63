"""``python -m maglev_cosim``: the command line (:mod:`maglev_cosim.cli`)."""

from .cli import main

raise SystemExit(main())
