"""``python -m fnsi_lab`` runs the CLI."""

import sys

from fnsi_lab.cli import main

sys.exit(main())
