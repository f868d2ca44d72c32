"""`python -m kinefuse`: the same as the `kinefuse` command."""

from kinefuse.app.cli.main import main

raise SystemExit(main())
