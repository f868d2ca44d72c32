"""`python -m kinefuse`: the same as the `kinefuse` command."""

from kinefuse.cli.main import main

raise SystemExit(main())
