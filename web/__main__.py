"""``python -m web``: run the browser dashboard (see :mod:`web.dashboard`)."""

import sys

from web.dashboard import main

sys.exit(main())
