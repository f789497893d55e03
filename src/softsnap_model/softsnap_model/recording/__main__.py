"""``python -m softsnap_model.recording``: see :func:`.cli.main`."""
import sys

from .cli import main

sys.exit(main())
