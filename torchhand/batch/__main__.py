"""``python -m torchhand.batch --stage DIR --threads K --device D -- METHOD SCENE ...``: one attempt of one batch
job, in its own process (:mod:`torchhand.batch.worker`)."""

import sys

from .worker import main

sys.exit(main())
