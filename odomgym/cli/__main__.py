"""``python -m odomgym.cli``: the same as the ``odomgym`` command."""

from odomgym.cli import main

raise SystemExit(main())
