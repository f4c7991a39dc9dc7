"""``python -m pmalab.acquisition.live.display RING CONFIG``: the display process of
``pmalab run --live`` (started by :class:`~.process.DisplayProcess`; see :mod:`.process`)."""

from __future__ import annotations

import json
import sys

from pmalab.acquisition.live.process import child_main

if __name__ == "__main__":
    sys.exit(child_main(sys.argv[1], json.loads(sys.argv[2])))
