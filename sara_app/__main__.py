"""``python -m sara_app``: the same as the ``sara-app`` command."""

import sys

from sara_app.cli import main

sys.exit(main())
