"""`python -m kinefuse`: the same as the `kinefuse` command."""

from kinefuse.cli import main

raise SystemExit(main())
